"""A pose graph of key poses, odometry edges and loop-closure edges, optimised by GTSAM.

Nodes are key poses ``T_world_key`` (4x4, the frame conventions of :mod:`slamlib.geometry`); an edge ``(i, j,
T_ij)`` says ``T_i^{-1} T_j = T_ij`` up to Gaussian noise in the tangent space of SE(3), with standard
deviations ``(rx, ry, rz, tx, ty, tz)`` (GTSAM's Pose3 order: rotation first, radians then metres). The
optimum minimises

.. math:: \\sum_{\\text{odometry}} \\| \\log(T_{ij}^{-1} T_i^{-1} T_j) \\|^2_{\\Sigma_{ij}}
          + \\sum_{\\text{closures}} \\rho\\big( \\| \\log(T_{ij}^{-1} T_i^{-1} T_j) \\|_{\\Sigma_{ij}} \\big)

with the first node held fixed by a tight prior. A closure enters only after a chi-square test (a false one
would have to bend the graph beyond its sigmas, :meth:`PoseGraph.optimise`), and then under a robust Huber
loss ``rho``, so one false closure cannot bend the map (Dellaert & Kaess, *Factor Graphs for Robot
Perception*, 2017, on robust pose graphs; Olson & Agarwal, *Inference on networks of mixtures for robust
robot mapping*, IJRR 2013, on why least squares alone cannot).

``gtsam`` (4.3.0 from the package registry, installed by ``make setup``) is imported when a graph is
optimised, not before.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "CLOSURE_SIGMAS",
    "INLIER_PROBABILITY",
    "ODOMETRY_SIGMAS_MIN",
    "ODOMETRY_SIGMAS_PER_M",
    "PRIOR_SIGMA",
    "Edge",
    "PoseGraph",
    "chi2_gate",
    "odometry_sigmas",
]

#: Standard deviations ``(rx, ry, rz (rad), tx, ty, tz (m))`` of an odometry edge between key poses, per metre
#: driven between them (:func:`odometry_sigmas`): 0.5 % of the distance and 0.003 degrees per metre, the
#: drift of the filter's odometry on KITTI-like drives.
ODOMETRY_SIGMAS_PER_M = np.array([5e-5, 5e-5, 5e-5, 5e-3, 5e-3, 5e-3])
#: Their floor (a few milliradians and centimetres), for key poses close together.
ODOMETRY_SIGMAS_MIN = np.array([1e-3, 1e-3, 1e-3, 0.02, 0.02, 0.02])
#: Those of a verified loop closure (a registration of two local maps).
CLOSURE_SIGMAS = np.array([5e-3, 5e-3, 5e-3, 0.1, 0.1, 0.1])
#: The first node's prior (fixes the gauge: the world frame is the first key pose).
PRIOR_SIGMA = 1e-6
#: A closure is kept when, with it, every edge's whitened squared error stays below this quantile of chi-square
#: with 6 degrees of freedom (:func:`chi2_gate`).
INLIER_PROBABILITY = 0.99


def chi2_gate(probability: float = INLIER_PROBABILITY, dof: int = 6) -> float:
    """The ``probability`` quantile of chi-square with an even number ``dof`` of degrees of freedom (16.81 at
    0.99 and 6), by bisection on the closed-form CDF for even ``dof = 2m``:
    ``F(x) = 1 - exp(-x/2) sum_{i<m} (x/2)^i / i!`` (the tests check it against ``scipy.stats.chi2``)."""
    if dof < 2 or dof % 2 or not 0 < probability < 1:
        raise ValueError(
            f"need an even dof >= 2 and 0 < probability < 1, got {dof}, {probability}"
        )

    def cdf(x):
        h = x / 2
        terms = np.cumprod(np.r_[1.0, h / np.arange(1, dof // 2)])
        return 1.0 - np.exp(-h) * terms.sum()

    lo, hi = 0.0, 1.0
    while cdf(hi) < probability:
        hi *= 2
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < probability else (lo, mid)
    return 0.5 * (lo + hi)


def odometry_sigmas(relative) -> np.ndarray:
    """``(6,)`` standard deviations of an odometry edge spanning ``relative`` (4x4): :data:`ODOMETRY_SIGMAS_PER_M`
    times the distance between its key poses, at least :data:`ODOMETRY_SIGMAS_MIN`."""
    distance = float(np.linalg.norm(np.asarray(relative)[:3, 3]))
    return np.maximum(ODOMETRY_SIGMAS_PER_M * distance, ODOMETRY_SIGMAS_MIN)


@dataclass(frozen=True)
class Edge:
    """``T_i^{-1} T_j = relative`` (4x4) with ``sigmas (6,)``; ``closure`` edges are robust."""

    i: int
    j: int
    relative: np.ndarray
    sigmas: np.ndarray
    closure: bool = False


def _gtsam():
    try:
        import gtsam
    except ImportError as exc:  # pragma: no cover - the message is the point
        raise ImportError(
            "loop closure needs GTSAM: `pip install gtsam==4.3.0` (or `make setup`, which installs it)"
        ) from exc
    return gtsam


@dataclass
class PoseGraph:
    """Key poses and edges; :meth:`optimise` returns the optimised key poses.

    Attributes
    ----------
    poses : dict id -> (4, 4) float64, the current estimate of each node (changed by :meth:`optimise`).
    edges : list of :class:`Edge`.
    closure_kept : (C,) bool, each closure decided so far: whether :meth:`optimise` kept it (in :attr:`closures`
        order).
    closure_statistic : (C,) float, the test each faced: the largest whitened squared error ``e^T Sigma^{-1} e``
        of any edge once the graph was solved with it, kept when at most :func:`chi2_gate`.
    """

    poses: dict = field(default_factory=dict)
    edges: list = field(default_factory=list)
    closure_kept: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    closure_statistic: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add_node(self, node: int, pose) -> None:
        """A node ``node`` at ``pose`` (4x4): its initial estimate."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"a pose is 4x4, got {pose.shape}")
        self.poses[int(node)] = pose.copy()

    def _edge(self, i, j, relative, sigmas, closure):
        for n in (i, j):
            if int(n) not in self.poses:
                raise KeyError(f"node {n} is not in the graph (add_node first)")
        sigmas = np.asarray(sigmas, dtype=np.float64).reshape(6)
        if not np.all(sigmas > 0):
            raise ValueError(f"sigmas must be positive, got {sigmas}")
        self.edges.append(
            Edge(
                int(i),
                int(j),
                np.asarray(relative, dtype=np.float64).copy(),
                sigmas,
                closure,
            )
        )

    def add_odometry(self, i: int, j: int, relative, sigmas=None) -> None:
        """An odometry edge ``T_i^{-1} T_j = relative`` (Gaussian; ``sigmas`` default :func:`odometry_sigmas`)."""
        self._edge(
            i, j, relative, odometry_sigmas(relative) if sigmas is None else sigmas, False
        )

    def add_closure(self, i: int, j: int, relative, sigmas=CLOSURE_SIGMAS) -> None:
        """A loop-closure edge ``T_i^{-1} T_j = relative`` (robust: kept or rejected by :meth:`optimise`)."""
        self._edge(i, j, relative, sigmas, True)

    @property
    def closures(self) -> list:
        """The closure edges."""
        return [e for e in self.edges if e.closure]

    def _factors(self, gtsam, edges, huber: float | None = None):
        """The prior on the first node and ``edges`` as GTSAM factors; closures under a Huber loss with its corner
        at ``huber`` whitened units when given."""
        graph = gtsam.NonlinearFactorGraph()
        first = min(self.poses)
        graph.add(
            gtsam.PriorFactorPose3(
                first,
                gtsam.Pose3(self.poses[first]),
                gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA),
            )
        )
        for e in edges:
            noise = gtsam.noiseModel.Diagonal.Sigmas(e.sigmas)
            if huber is not None and e.closure:
                noise = gtsam.noiseModel.Robust.Create(
                    gtsam.noiseModel.mEstimator.Huber.Create(huber), noise
                )
            graph.add(gtsam.BetweenFactorPose3(e.i, e.j, gtsam.Pose3(e.relative), noise))
        return graph

    def _values(self, gtsam):
        values = gtsam.Values()
        for node, pose in self.poses.items():
            values.insert(node, gtsam.Pose3(pose))
        return values

    def optimise(self, max_iterations: int = 100) -> dict:
        """Decide the closures not yet decided, then minimise the graph's error over the odometry and the kept
        closures, the first node (lowest id) held by a tight prior; updates and returns :attr:`poses`.

        Each undecided closure, in the order added, faces a **chi-square test**: the graph of the odometry,
        the closures kept so far and the new one is solved by Levenberg-Marquardt, and the closure is kept when
        afterwards every edge's whitened squared error ``e^T Sigma^{-1} e`` is below :func:`chi2_gate` (the
        :data:`INLIER_PROBABILITY` quantile of chi-square with 6 degrees of freedom). A true closure is
        absorbed by bending each odometry edge a little; a false one can only be met by bending some edge far
        beyond its sigmas, and is left out altogether, so it cannot bend the map. The final solve puts the kept
        closures under a Huber loss with its corner at the gate (a second line of defence: beyond it, a closure
        pulls linearly, not quadratically; Huber 1964).
        """
        if not self.poses:
            return {}
        gtsam = _gtsam()
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(int(max_iterations))
        gate = chi2_gate()
        while len(self.closure_kept) < len(self.closures):
            new = self.closures[len(self.closure_kept)]
            graph = self._factors(gtsam, self._kept_edges() + [new])
            trial = gtsam.LevenbergMarquardtOptimizer(
                graph, self._values(gtsam), lm
            ).optimize()
            worst = max(2 * graph.at(k).error(trial) for k in range(1, graph.size()))
            self.closure_kept = np.append(self.closure_kept, worst <= gate)
            self.closure_statistic = np.append(self.closure_statistic, worst)
        result = gtsam.LevenbergMarquardtOptimizer(
            self._factors(gtsam, self._kept_edges(), huber=np.sqrt(gate)),
            self._values(gtsam),
            lm,
        ).optimize()
        self.poses = {node: result.atPose3(node).matrix() for node in self.poses}
        return self.poses

    def _kept_edges(self) -> list:
        """The odometry edges and the closures decided and kept."""
        kept = [c for c, k in zip(self.closures, self.closure_kept) if k]
        return [e for e in self.edges if not e.closure] + kept
