"""What the multi-step scorer keeps of each candidate it fits (:class:`EndCapFits`):
the fits selection compares, the model reported, and its held-out error."""

from __future__ import annotations

from dataclasses import dataclass

from identification.trajectory.end_cap_data import TrajFit
from identification.trajectory.floor_declared import FloorFit
from identification.trajectory.windows import Windows


@dataclass
class EndCapFits:
    """What the multi-step scorer fitted for one candidate.

    Attributes:
        fit: the fit on the training windows that selection compares on.
        final: the fit on the many windows (the model reported and tested); ``fit``
            for a candidate not accepted.
        val_sse, val_m: held-out (validation) sum of squared end-cap errors [m^2] and
            number of residuals, only the windows' states fitted.
        val_windows: those windows, states fitted.
    """

    fit: TrajFit
    final: TrajFit
    val_sse: float = float("nan")
    val_m: int = 0
    val_windows: Windows | None = None
    #: the current model refitted as every candidate is (from ``fit``'s origin and
    #: windows, with the candidates' iterations): what its held-out error and BIC are
    #: measured on (None: ``fit``)
    reference: TrajFit | None = None
    #: on the floor, the floor fit done afresh with the candidate's effects that ``fit``
    #: started from (a candidate fitted jointly, see ``MultiStepScorer.second_look``;
    #: None: screened with the rest held)
    floor: FloorFit | None = None

    @property
    def scored(self) -> TrajFit:
        """The fit the held-out error and the BIC are measured on."""
        return self.fit if self.reference is None else self.reference
