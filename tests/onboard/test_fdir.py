"""On-board fault detectors (onboard.fdir) on scripted sample sequences."""
from magtune_core.onboard.fdir import BACK, LOST, SunSensorWatch


def test_sun_sensor_lost_after_its_count_of_lit_samples_and_back_at_the_first_sample():
    """Eclipse samples (predicted dark) never count; a lit gap shorter than the count is ridden through; the
    loss is reported once, at the count-th lit sample without sun; the first sun sample reports it back."""
    w = SunSensorWatch(loss_samples=5)
    script = [(True, True)] * 3 + [(False, False)] * 50 + [(True, False)] * 4 + [(True, True)] \
        + [(True, False)] * 7 + [(True, True)] * 2
    verdicts = [(k, v) for k, (lit, sun) in enumerate(script) if (v := w.step(lit, sun)) is not None]
    start = 3 + 50 + 4 + 1  # the second lit gap starts here
    assert verdicts == [(start + 4, LOST), (start + 7, BACK)], verdicts


def test_sun_sensor_watch_off():
    """loss_samples 0: never lost."""
    w = SunSensorWatch(loss_samples=0)
    assert all(w.step(True, False) is None for _ in range(1000)) and not w.lost
