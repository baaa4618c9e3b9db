"""magtune_core.base.paramfile: what rcl's parameter-file parser rejects although PyYAML loads it."""
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import check_ros_params


@pytest.mark.parametrize("value, ok", [
    ("[1.0, 2.5]", True), ("[1, 2]", True), ("[a, b]", True), ("[]", True), ("{a: 1.0}", True),
    ("[1, 2.5]", False), ("[[1.0, 2.0], [3.0, 4.0]]", False), ("[1.0, null]", False), ("[x, y]", False),
])
def test_rcl_rules(tmp_path, value, ok):
    f = tmp_path / "p.yaml"
    f.write_text(f"controller:\n  ros__parameters:\n    gain_meta:\n      x: {value}\n")
    if ok:
        check_ros_params(f)
    else:
        with pytest.raises(ConfigError, match="gain_meta.x"):
            check_ros_params(f)
