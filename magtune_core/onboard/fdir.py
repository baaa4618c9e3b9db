"""On-board fault detection: small detectors that watch one unit each and say when it failed and when it is back.

Each detector is pure (no clock, no I/O): the node that holds the unit's data steps it once per sample
and reports its verdicts on /diagnostics (WARN naming the unit at the sample of detection, OK when
it is back), so the SIL, and later the batched campaigns, run the same decision.

* :class:`SunSensorWatch`: the sun sensor is lost after ``loss_samples`` consecutive samples that the
  on-board eclipse model predicts lit but that bring no sun sample. It assumes sun sensors that cover
  the whole sphere (coarse sensors on every face, the default suite): with a narrower field of view,
  lit-but-out-of-view samples are normal and the watch needs the view model too.
"""
from __future__ import annotations

from dataclasses import dataclass

LOST, BACK = "lost", "back"


@dataclass
class SunSensorWatch:
    """Lost after ``loss_samples`` predicted-lit samples in a row without a sun sample (0: never); back at the
    first sun sample after that."""

    loss_samples: int = 10
    missing: int = 0
    lost: bool = False

    def step(self, predicted_lit: bool, have_sun: bool) -> str | None:
        """Take one processed sample; the verdict when it changes.

        Parameters
        ----------
        predicted_lit : bool
            The on-board eclipse model puts the satellite in sunlight at this sample.
        have_sun : bool
            A sun sample came with it.

        Returns
        -------
        str or None
            :data:`LOST` at the sample the loss is detected, :data:`BACK` at the first sun sample after a
            loss, else None.
        """
        if have_sun:
            self.missing = 0
            if self.lost:
                self.lost = False
                return BACK
            return None
        if predicted_lit and self.loss_samples > 0:
            self.missing += 1
            if not self.lost and self.missing >= self.loss_samples:
                self.lost = True
                return LOST
        return None
