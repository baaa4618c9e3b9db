"""Studies built on simulation and bags: the sampling-period study (``sampling``) and the
paper's Figs. 2-5 from recorded bags (``report``). No argparse: commands live in ``cli``.
"""
