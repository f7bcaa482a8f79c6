"""How one deputy of one run is scored: the one rule the run report, the sweeps and the
campaigns share (:func:`deputy_metrics`).

- along-track error |y - y_ref|: at the end, and its largest value over the last orbit (m);
- learned (None for an LQR deputy): the gains flown at the end are ones the learner learned,
  not K0 while it explores, nor the old gains a failed re-learning fell back to;
- learned at: the orbit of its first switch to learned gains (None: never);
- fallback at: the orbit a learner took to its fallback, the nominal model's LQR gains, having
  validated no gain (None: never; ``services.flight.phases``);
- gain error |K - K*| / |K*| of the gain flown at the end against K*, the optimal gain of the
  truth's linear model of that run (``services.model.true_lqr_gains``), and against the nominal
  model's LQR gain: only for an LQR deputy's gain and a learner's fallback (against K* alone)
  and a learned gain.  A learner that flies neither at the end has none (None: "not
  learned");
- can hold: some attitude within its limit matches the chief's drag
  (``services.model.holding_problems``); where none does the note says so;
- note: why the deputy cannot hold its slot, and why a learner flies no learned gain (its
  controller's last log line).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from services.config import Deployment, Deputy
from services.ground.analysis.rundata import GainRecord, truth_hill
from services.model import holding_problems, lqr_gains, orbit_period, reference_gains

log = logging.getLogger("ddvi.scoring")

FloatArray = NDArray[np.float64]

NOT_LEARNED = ("lqr", "initial", "fallback")
"""Gain sources that are not learned: the nominal LQR gain, K0 while exploring, the old gains
a failed re-learning fell back to.  Any other source is a learner's."""


def learned_switches(gains: Sequence[GainRecord]) -> list[float]:
    """When (s) a controller's gains switched to learned ones from others, in order: its first
    learning, then each re-learning."""
    return [
        r.t
        for k, r in enumerate(gains)
        if r.source not in NOT_LEARNED and (k == 0 or gains[k - 1].source != r.source)
    ]


def switches_to(gains: Sequence[GainRecord], source: str) -> list[float]:
    """When (s) a controller's gains switched to ``source`` from others, in order: a learner's
    to "lqr" are its fallback, the nominal model's LQR gains (``services.flight.phases``);
    to "fallback", a failed re-learning's return to the old gains."""
    return [
        r.t
        for k, r in enumerate(gains)
        if r.source == source and k > 0 and gains[k - 1].source != source
    ]


NOT_LEARNED_TEXT = "not learned"
"""What a table prints for the gain error of a learner that flies no learned gain."""

METRICS = (
    "completed",
    "final_along_track_error_m",
    "max_along_track_error_last_orbit_m",
    "learned",
    "learned_at_orbits",
    "fallback_at_orbits",
    "gain_error",
    "gain_error_vs_lqr",
    "can_hold",
    "note",
)
"""The keys of :func:`deputy_metrics`, in table order."""

NOTE_LENGTH = 160  # characters of a learner's last log line kept as a note


@dataclass(frozen=True)
class Success:
    """What a table counts as a deputy's success, named by the table that uses it: each bound
    given must hold in a run that completed.

    Parameters
    ----------
    name : what the table says it counts, e.g. "learned within 10 % of K*".
    gain_below : a learned gain with |K - K*| / |K*| below this.
    final_below_m : a final along-track error below this, m.
    lqr_factor, floor_m : a final along-track error at most max(lqr_factor x the LQR deputy's
        of the same run, floor_m), m.
    """

    name: str
    gain_below: float | None = None
    final_below_m: float | None = None
    lqr_factor: float | None = None
    floor_m: float = 0.0

    def met(
        self,
        *,
        completed: bool,
        final_m: float | None = None,
        learned: bool | None = None,
        gain_error: float | None = None,
        lqr_final_m: float | None = None,
    ) -> bool:
        """Whether a deputy's figures (``deputy_metrics``'s: an LQR deputy has ``learned``
        None) meet every bound given; a figure a bound needs that is missing fails it."""
        if not completed:
            return False
        if self.gain_below is not None and not (
            learned and gain_error is not None and gain_error < self.gain_below
        ):
            return False
        if self.final_below_m is not None and not (
            final_m is not None and final_m < self.final_below_m
        ):
            return False
        if self.lqr_factor is None:
            return True
        if final_m is None or lqr_final_m is None:
            return False
        return final_m <= max(self.lqr_factor * lqr_final_m, self.floor_m)

    def row_met(self, row: dict[str, Any]) -> bool:
        """``met`` of a row of :data:`METRICS` (a figure it lacks is missing)."""
        return self.met(
            completed=bool(row.get("completed")),
            final_m=row.get("final_along_track_error_m"),
            learned=row.get("learned"),
            gain_error=row.get("gain_error"),
        )


LEARNED_WITHIN_10_PERCENT = Success("learned within 10 % of K*", gain_below=0.1)
"""The sweeps' success: the controller switched to learned gains within 10 % of the optimal
gain of the truth's linear model; a learner can also converge to a wrong gain."""

AS_GOOD_AS_LQR = Success("final error within max(2x the LQR's, 10 m)", lqr_factor=2.0, floor_m=10.0)
"""The twin benchmark's success: a final error no worse than twice the LQR deputy's of the same
draw, or 10 m, whichever is larger."""


def final_error_below(metres: float) -> Success:
    """A campaign's success: a final along-track error below its ``success_threshold``."""
    return Success(f"final error < {metres:g} m", final_below_m=metres)


@dataclass
class DeputyOutcome:
    """What one run produced for one deputy: sample times t (s) and |y - y_ref| at them (m),
    the gain K (1, 4) flown at the end and its source (a ``gains`` message's), every switch to
    learned gains (s), every switch to the LQR fallback (s), the learner's log lines, and
    whether the run completed."""

    t: FloatArray
    along_track_error: FloatArray
    K: FloatArray | None
    source: str | None
    learned_at: Sequence[float] = ()
    log: Sequence[str] = ()
    completed: bool = True
    fallback_at: Sequence[float] = ()


def scored_gain_error(K: Any, K_ref: FloatArray | None) -> float | None:
    """|K - K_ref| / |K_ref| (Frobenius norms); None without K or a reference, or with a shape
    or zero reference that makes no sense of it."""
    # scipy (ddvi_core.lqr's) only when a report scores: the monitor loads this at its start
    from ddvi_core.lqr import relative_gain_error

    if K is None or K_ref is None:
        return None
    K = np.asarray(K, float)
    if K.shape != K_ref.shape or not np.any(K_ref) or not np.all(np.isfinite(K)):
        return None
    return relative_gain_error(K, K_ref)


def holding_notes(dep: Deployment) -> dict[str, str]:
    """Deputy name -> why it cannot hold its slot (its warnings joined); deputies that can
    are absent."""
    out: dict[str, list[str]] = {}
    for name, text in holding_problems(dep):
        out.setdefault(name, []).append(text)
    return {name: "; ".join(texts) for name, texts in out.items()}


def short_note(text: str) -> str:
    """A log line as a table note: at most ``NOTE_LENGTH`` characters, cut at a word."""
    if len(text) <= NOTE_LENGTH:
        return text
    return text[:NOTE_LENGTH].rsplit(" ", 1)[0] + " ..."


def deputy_metrics(
    dep: Deployment,
    deputy: Deputy,
    outcome: DeputyOutcome,
    *,
    K_true: FloatArray | None = None,
    K_lqr: FloatArray | None = None,
    cannot_hold: str | None = None,
) -> dict[str, Any]:
    """The deputy's metrics (keys :data:`METRICS`; see the module's docstring).  ``K_true``,
    ``K_lqr`` and ``cannot_hold`` (why it cannot hold its slot; "" when it can) are computed
    from ``dep`` when not given."""
    lqr = deputy.controller == "lqr"
    learner = deputy.controller == "ddvi"  # a ROS 2-flown deputy's gains are its node's own
    period = orbit_period(dep)
    learned = outcome.source is not None and outcome.source not in NOT_LEARNED
    falling_back = learner and outcome.source == "lqr"  # its fallback: the LQR's gains
    scored = lqr or learned or falling_back
    if scored and K_true is None:
        K_true = reference_gains(dep, deputy)[0]
    if learned and K_lqr is None:
        K_lqr = np.asarray(lqr_gains(dep, deputy)[0])
    if cannot_hold is None:
        cannot_hold = holding_notes(dep).get(deputy.name, "")
    ey = np.asarray(outcome.along_track_error, float)
    t = np.asarray(outcome.t, float)
    notes = [cannot_hold] if cannot_hold else []
    if learner and not learned:
        notes.append(short_note(outcome.log[-1]) if outcome.log else "no learning attempt")
    return {
        "completed": bool(outcome.completed),
        "final_along_track_error_m": float(ey[-1]) if len(ey) else None,
        "max_along_track_error_last_orbit_m": float(ey[t >= t[-1] - period].max())
        if len(ey)
        else None,
        "learned": learned if learner else None,
        "learned_at_orbits": None
        if not learner or not outcome.learned_at
        else float(outcome.learned_at[0] / period),
        "fallback_at_orbits": None
        if not learner or not outcome.fallback_at
        else float(outcome.fallback_at[0] / period),
        "gain_error": scored_gain_error(outcome.K, K_true) if scored else None,
        "gain_error_vs_lqr": scored_gain_error(outcome.K, K_lqr) if learned else None,
        "can_hold": not cannot_hold,
        "note": "; ".join(notes) or None,
    }


def inprocess_outcome(dep: Deployment, deputy: Deputy, rec: dict[str, Any]) -> DeputyOutcome:
    """One deputy's outcome from ``services.flight.inprocess.run_in_process``'s record of it:
    the along-track error of its truth Hill state at every truth sample, as a report has it."""
    c = rec["controller"]
    hill = truth_hill(dep, np.asarray(rec["chief_rv"]), np.asarray(rec["rv"]))
    return DeputyOutcome(
        t=np.asarray(rec["truth_t"]),
        along_track_error=np.abs(hill[:, 1] - deputy.y_ref),
        K=np.asarray(c.K),
        source=c.source,
        learned_at=list(c.learning.learned_at),
        log=list(rec.get("log", [])),
        fallback_at=list(c.learning.fallback_at),
    )


def failed_metrics(deputy: Deputy, why: str, cannot_hold: str = "") -> dict[str, Any]:
    """The metrics of a deputy whose run ended before it could be scored (a re-entry, say)."""
    out: dict[str, Any] = dict.fromkeys(METRICS)
    notes = [cannot_hold] if cannot_hold else []
    out.update(
        completed=False,
        can_hold=not cannot_hold,
        note="; ".join([*notes, short_note(why)]),
    )
    return out


def table_cell(key: str, row: dict[str, Any]) -> Any:
    """A metric as a table prints it: "not learned" for the gain errors of a learner that
    flies no learned gain (but its fallback's error against K*), else the value."""
    if key == "gain_error_vs_lqr" and row.get("learned") is False:
        return NOT_LEARNED_TEXT
    if key == "gain_error" and row.get("learned") is False and row.get("gain_error") is None:
        return NOT_LEARNED_TEXT
    return row.get(key)
