"""Re-learning after a change of the plant (``learning.relearn``): the change detector a
learner arms on the data it learned from (ddvi_core.detection's one-step predictor, and the
one-orbit mean of its input-equivalent residual against the bound it states in its log), and
what the controller keeps while it re-learns."""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any

import numpy as np

from ddvi_core.detection import ChangeDetector, DetectionError, fit_predictor
from ddvi_core.learning_config import LearningConfig


@dataclass
class Relearning:
    """While re-learning: what was flown before the detection (K, L, the exosystem (C, E, F)
    they were learned on, when they were learned, and the learner's store and the rank that
    learned them), flown again if re-learning fails ``relearn_max_attempts`` times; ``since``,
    when the data for re-learning start, and ``window`` (s), the newest span it learns from;
    the count of failed attempts."""

    K: np.ndarray
    L: np.ndarray
    exosystem: tuple
    learned_at: float
    store: Any
    rank: tuple[int, int]
    since: float
    window: float
    failures: int = 0

    def window_start(self, t: float) -> float:
        """The first sample time (s) an attempt at t learns from: the newest ``window`` since
        settling."""
        return max(self.since, t - self.window)


class ChangeWatch:
    """The samples the learner collects (t, x, u, v), for the predictor the detector fits
    when it learns; the detector once armed (None: not watching); the count of detections.
    ``step`` (s): the navigation period; ``orbit`` (s): the orbit period."""

    def __init__(self, lrn: LearningConfig, step: float, orbit: float) -> None:
        self.lrn, self.step, self.orbit = lrn, step, orbit
        self.samples: collections.deque = collections.deque()
        self.detector: ChangeDetector | None = None
        self.detections = 0

    def record(self, t: float, x: np.ndarray, u: float, v: np.ndarray) -> None:
        """A sample the learner collected, kept for the predictor."""
        self.samples.append((t, np.array(x, dtype=float), u, np.array(v, dtype=float)))

    def add(self, t: float, x: np.ndarray, u: float, v: np.ndarray) -> bool:
        """A sample flown on the learned gains, to the detector if armed; whether it was."""
        if self.detector is None:
            return False
        self.detector.add(t, x, [u], v)
        return True

    @property
    def alarm(self) -> bool:
        return self.detector is not None and self.detector.alarm

    def arm(self, since: float, q: int) -> str:
        """Fit the one-step predictor on the samples the learner just learned from (those at
        or after ``since``, exostates of ``q`` components) and watch it from now on; returns
        the log's words on the bound it states."""
        lrn = self.lrn
        samples = [s for s in self.samples if s[0] >= since - 1e-6]
        try:
            predictor = fit_predictor(
                [s[0] for s in samples],
                np.reshape([s[1] for s in samples], (len(samples), 4)),
                [s[2] for s in samples],
                np.reshape([s[3] for s in samples], (len(samples), q)),
                step=self.step,
                translation=[0.0, 1.0, 0.0, 0.0] if lrn.along_track_reference else None,
            )
            window = lrn.detector_window_orbits * self.orbit
            self.detector = ChangeDetector(predictor, lrn.detector_bound, window)
        except DetectionError as exc:
            self.detector = None
            return f"; fault detector NOT armed (no re-learning): {exc}"
        finally:
            self.samples.clear()
        return (
            f"; fault detector: bound = +-{self.detector.bound[0]:.4g} on the "
            f"{lrn.detector_window_orbits:g}-orbit mean input-equivalent one-step prediction "
            f"residual ({lrn.detector_bound:g} x its RMS {predictor.input_rms[0]:.3g} on the "
            f"{predictor.pairs} sample pairs learned from; one-step residual RMS "
            f"{np.array2string(predictor.residual_rms, precision=3)})"
        )

    def detected(self) -> str:
        """The detector has alarmed: count it, stop watching (re-learning collects afresh) and
        return the log's words on what it saw."""
        det, lrn = self.detector, self.lrn
        self.detections += 1
        self.detector = None
        self.samples.clear()
        return (
            f"the {lrn.detector_window_orbits:g}-orbit mean "
            f"input-equivalent prediction residual {det.mean[0]:+.4g} left the bound "
            f"+-{det.bound[0]:.4g} ({det.statistic:.2f} x the bound): the plant has changed"
        )

    def disarm(self) -> None:
        """Watch no more (the old gains fly again: the detector would only see the same
        change again), and forget the samples collected for re-learning."""
        self.detector = None
        self.samples.clear()
