"""Compute backends for the 3D particle filter: ``get_backend("numpy" | "cpu" | "cuda")``.

Every backend provides the same four functions (CONTRIBUTING.md, "Backend interface (3D)"):

``move_particles(R (P,3,3) f8, t (P,3) f8, rpy_delta (3,), trans_delta (3,), noise (P,6), sigma (6,))``
    -> ``(R_new, t_new)``: steps 5 + 6 fused, ``R_new = R_i dR N_i``,
    ``t_new = t_i + R_i dR (trans_delta + sigma[:3] * noise[i, :3])`` with ``dR = rpy_to_matrix(rpy_delta)``
    and ``N_i = rpy_to_matrix(sigma[3:] * noise[i, 3:])``.
``transform_points(T (4,4), points (N,3) f4, out=None)`` -> ``(N,3) f4``: ``p' = R p + t``; ``out`` receives the
    result (``out=points``: in place) on the numpy and CPU backends.
``noise`` of ``move_particles`` may also be a :class:`slamlib.noise.LutNoise` (the draws of ``noise.draw(P)``,
    generated inside the kernel on CPU and CUDA), and the numpy and CPU backends take ``out=(R_out, t_out)``.
``score_particles(R (P,3,3) f8, t (P,3) f8, points_body (N,3) f4, lookup)`` -> ``(P,) f8`` log-likelihoods,
    fused transform + map lookup (see :mod:`slamlib.maps.base` for the lookup tuples and the per-point terms).
``systematic_resample(weights (P,), u0 in [0, 1))`` -> ``(P,) int64`` indexes (Kitagawa 1996; the filterpy
    ``systematic_resample`` with its random offset passed in as ``u0``).

``"numpy"`` is :mod:`slamlib.kernels.reference` (plain numpy, the ground truth of the tests), ``"cpu"`` is
:mod:`slamlib.kernels.cpu` (Numba ``@njit(parallel=True)``), ``"cuda"`` is :mod:`slamlib.kernels.cuda`
(numba.cuda), imported only when asked for.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

from slamlib.errors import BackendUnavailableError

BACKENDS = ("numpy", "cpu", "cuda")
#: The backend used when none is named: :func:`get_backend`, the 3D step functions
#: (:mod:`slamlib.slam3d.steps`) and :attr:`slamlib.slam3d.config.SLAM3DConfig.backend` take it from here.
DEFAULT_BACKEND = "cpu"
_MODULES = {
    "numpy": "slamlib.kernels.reference",
    "cpu": "slamlib.kernels.cpu",
    "cuda": "slamlib.kernels.cuda",
}
_FUNCTIONS = (
    "move_particles",
    "transform_points",
    "score_particles",
    "systematic_resample",
)


@dataclass(frozen=True)
class Backend:
    """The four kernels of one backend, as plain attributes (``backend.score_particles(...)``)."""

    name: str
    move_particles: Callable
    transform_points: Callable
    score_particles: Callable
    systematic_resample: Callable


def get_backend(name: str = DEFAULT_BACKEND) -> Backend:
    """Return the backend called ``name`` (``"numpy"``, ``"cpu"`` or ``"cuda"``).

    The module behind it is imported on first use. For ``"cuda"``, :mod:`slamlib.kernels.cuda` must define the
    four functions at module level; it may define ``check_available()`` that raises
    :class:`~slamlib.errors.BackendUnavailableError` when no GPU can be used (called here), and an
    ``ImportError`` while importing it is turned into that error too.

    Raises
    ------
    ValueError
        Unknown ``name``.
    BackendUnavailableError
        ``"cuda"`` on a machine without a usable GPU / numba-cuda.
    """
    if name not in _MODULES:
        raise ValueError(f"unknown backend {name!r}; choose one of {', '.join(BACKENDS)}")
    try:
        module = importlib.import_module(_MODULES[name])
    except ImportError as exc:
        if name == "cuda":
            raise BackendUnavailableError(
                f"the CUDA backend cannot be imported ({exc}); install it with `pip install numba-cuda[cu12]` "
                'on a machine with an NVIDIA GPU, or use backend="cpu"'
            ) from exc
        raise
    check = getattr(module, "check_available", None)
    if check is not None:
        check()
    return Backend(name, *(getattr(module, f) for f in _FUNCTIONS))
