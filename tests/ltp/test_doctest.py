"""The examples in magtune_core.ltp's docstrings run and print what they say (doctest)."""
import doctest
import importlib
import pkgutil

import magtune_core.ltp as ltp


def test_ltp_docstring_examples():
    """doctest of the package docstring (the LTI oscillator: H-inf, multipliers, H2 against their
    closed forms) and of every submodule (any example added there is run too)."""
    package = doctest.testmod(ltp)
    assert package.attempted > 0 and package.failed == 0  # the package example exists and passes
    subs = [doctest.testmod(importlib.import_module(f"{ltp.__name__}.{m.name}")) for m in pkgutil.iter_modules(ltp.__path__)]
    failed = sum(r.failed for r in subs)
    assert failed == 0, f"{failed} doctest examples of ltp's submodules failed (see the output above)"
