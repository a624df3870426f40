"""Where a frame's time goes: the per-stage profile of :meth:`ParticleSLAM3D.register_frame`.

:class:`StageProfile` times every stage of the twelve steps while it is attached to a filter
(``with profile.attached(slam): ...``), each by its **own** time: a stage called inside another (the weighing of
steps 7 + 8 inside an annealing round, step 6's perturbation inside it too) is counted once, under its own name,
and taken out of the stage that called it. So the stages' times add up to the frames' wall time, and
``"bookkeeping"`` is what ``register_frame`` spends outside every stage (the poses kept, the last frame's record).

The stages (:data:`STAGES`, in the order of a frame):

=================  ==========================================================================================
name               what it times
=================  ==========================================================================================
``read_motion``    step 3: the IMU sample, or LIDAR-only the held twist (``motion.read``)
``read_scan``      step 2: crop, down-sampling, de-skewing (``scan.read``)
``predict``        the increment and step 6's spread for it, self-tuning's correction (``motion.predict``)
``move``           step 5 (:func:`~slamlib.slam3d.steps.offset_by_motion`)
``perturb``        step 6, also inside annealing rounds (:func:`~slamlib.slam3d.steps.perturb_with_noise`)
``prior``          the tilt prior's measurement of the accelerometer's up (``prior.measure``)
``sample``         step 8's points drawn from the scan (``motion.scoring_sample``)
``weigh``          steps 7 + 8: transform and score every particle, the prior's term (``ParticleSLAM3D.weigh``)
``resample``       step 11, and the resampling inside annealing rounds
``anneal``         the annealing rounds' own time, their weighing, perturbing and resampling counted above
``pick``           step 9 (:func:`~slamlib.slam3d.steps.pick_best_particle`)
``scan_match``     the polish of step 9's pose (``polish``: scan matching, on by default)
``learn``          self-tuning and the tilt prior's calibration from the chosen pose
``merge``          step 10 (:func:`~slamlib.slam3d.steps.merge_scan`)
``upkeep``         map pruning and transient eviction (``upkeep``)
``bookkeeping``    the rest of ``register_frame``
``loop_closure``   the loop closer's work, when one is attached (``closer.add_frame``, ``closer.finish``): local
                   maps, loop candidates, their verification, the pose graph; outside ``register_frame``, as in
                   ``slamlib run --loop-closure`` (:func:`~slamlib.slam3d.run.run_drive`)
=================  ==========================================================================================

Timing uses ``time.perf_counter``; the wrappers add about a microsecond per call. The profile patches the module
functions of :mod:`slamlib.slam3d.steps` that the pipeline calls while attached (every caller sees the timed ones
then), and restores them on leaving.
"""

from __future__ import annotations

import functools
import time
from collections import Counter, defaultdict
from contextlib import contextmanager

from slamlib.slam3d import steps

__all__ = ["STAGES", "StageProfile"]

STAGES = (
    "read_motion",
    "read_scan",
    "predict",
    "move",
    "perturb",
    "prior",
    "sample",
    "weigh",
    "resample",
    "anneal",
    "pick",
    "scan_match",
    "learn",
    "merge",
    "upkeep",
    "bookkeeping",
    "loop_closure",
)
#: The functions of :mod:`slamlib.slam3d.steps` timed while attached, and their stage.
STEP_FUNCTIONS = {
    "offset_by_motion": "move",
    "perturb_with_noise": "perturb",
    "resample_particles": "resample",
    "pick_best_particle": "pick",
    "merge_scan": "merge",
}


class StageProfile:
    """Seconds and calls per stage (:data:`STAGES`), each stage by its own time (module docstring).

    ``seconds[name]`` and ``calls[name]``; ``frames`` the frames registered while attached;
    :meth:`ms_per_frame` the table a benchmark reports.
    """

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: Counter = Counter()
        self.frames = 0
        self._inner: list[float] = []

    def timed(self, name: str, fn):
        """``fn`` wrapped to add its own time (less that of timed calls inside it) to stage ``name``."""

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            self._inner.append(0.0)
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                total = time.perf_counter() - t0
                inner = self._inner.pop()
                self.seconds[name] += total - inner
                self.calls[name] += 1
                if self._inner:
                    self._inner[-1] += total

        return wrapper

    @contextmanager
    def attached(self, slam, closer=None):
        """Time ``slam``'s stages inside the ``with`` block, and those of ``closer`` (a
        :class:`slamlib.loops.LoopCloser` fed by the caller) as ``loop_closure``. ``slam`` must have registered its
        first frame (the stages that depend on the data are chosen then)."""
        if slam.motion is None:
            raise ValueError(
                "attach the profile after the first frame: the filter's stages are chosen on it"
            )
        patched = []  # (object, attribute, original); instance attributes are deleted again

        def wrap(obj, attr, name):
            original = getattr(obj, attr)
            own = attr in vars(obj)
            patched.append((obj, attr, original if own else None))
            setattr(obj, attr, self.timed(name, original))

        for fn, name in STEP_FUNCTIONS.items():
            wrap(steps, fn, name)
        wrap(slam.motion, "read", "read_motion")
        wrap(slam.motion, "predict", "predict")
        wrap(slam.motion, "scoring_sample", "sample")
        wrap(slam.scan, "read", "read_scan")
        wrap(slam.prior, "measure", "prior")
        wrap(slam, "weigh", "weigh")
        # the annealing stage calls slam.weigh through the bound method it was given
        wrap(slam.search, "weigh", "weigh")
        wrap(slam, "search", "anneal")
        wrap(slam, "polish", "scan_match")
        wrap(slam, "_learn", "learn")
        wrap(slam, "upkeep", "upkeep")
        wrap(slam, "register_frame", "bookkeeping")
        if closer is not None:
            wrap(closer, "add_frame", "loop_closure")
            wrap(closer, "finish", "loop_closure")
        timed_frame = slam.register_frame

        def counted(frame):
            self.frames += 1
            return timed_frame(frame)

        slam.register_frame = counted
        try:
            yield self
        finally:
            for obj, attr, original in reversed(patched):
                if original is None:
                    delattr(obj, attr)
                else:
                    setattr(obj, attr, original)

    def ms_per_frame(self) -> dict[str, float]:
        """Milliseconds per registered frame of each stage (:data:`STAGES` order, every stage present)."""
        n = max(self.frames, 1)
        return {name: 1e3 * self.seconds.get(name, 0.0) / n for name in STAGES}
