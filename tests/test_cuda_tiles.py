"""The tiled scoring layout of the CUDA backend (blocks over particle x point tiles, then a per-particle sum)
against the numpy reference and the one-block-per-particle layout, in Numba's CUDA simulator (tiny sizes)."""

import numpy as np
import pytest

from slamlib import geometry
from slamlib.kernels import cuda as kc
from slamlib.kernels import reference as ref


@pytest.mark.parametrize("which", [0, 1], ids=["voxel_hash", "morton_bvh"])
@pytest.mark.parametrize("n, tile_points", [(37, 8), (37, 37), (37, 100), (0, 8)])
def test_tiled_scores_equal_the_reference(street_maps, which, n, tile_points):
    """Tiles that split the points unevenly (37 = 4 x 8 + 5), one tile of all of them, one tile larger than the
    scan, and no points at all."""
    world, lookups = street_maps
    rng = np.random.default_rng(7 + which)
    P = 3
    R = geometry.rpy_to_matrix(rng.normal(0, 0.05, (P, 3)))
    t = rng.normal(0, 0.3, (P, 3))
    pts = (
        world[rng.choice(len(world), n, replace=False)] + rng.normal(0, 0.05, (n, 3))
    ).astype(np.float32)
    got = kc.score_particles(
        R, t, pts, lookups[which], threads=4, layout="tiles", tile_points=tile_points
    )
    want = ref.score_particles(R, t, pts, lookups[which])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    blocks = kc.score_particles(R, t, pts, lookups[which], threads=4)
    np.testing.assert_allclose(got, blocks, rtol=1e-12, atol=1e-12)
    if n:
        assert np.ptp(got) > 0.1  # the particles are told apart


def test_tiled_layout_keeps_device_arrays_on_the_device(street_maps):
    world, lookups = street_maps
    rng = np.random.default_rng(9)
    R = geometry.rpy_to_matrix(rng.normal(0, 0.05, (2, 3)))
    t = rng.normal(0, 0.3, (2, 3))
    pts = world[:20]
    dev = kc.score_particles(
        kc.to_device(R),
        kc.to_device(t),
        kc.to_device(pts),
        kc.lookup_to_device(lookups[0]),
        threads=4,
        layout="tiles",
        tile_points=6,
    )
    assert kc.is_device_array(dev)
    np.testing.assert_allclose(
        kc.to_host(dev), ref.score_particles(R, t, pts, lookups[0]), rtol=1e-9, atol=1e-9
    )


def test_layout_and_tile_size_are_checked(street_maps):
    world, lookups = street_maps
    R, t = np.eye(3)[None], np.zeros((1, 3))
    with pytest.raises(ValueError, match="layout"):
        kc.score_particles(R, t, world[:4], lookups[0], layout="rows")
    with pytest.raises(ValueError, match="tile_points"):
        kc.score_particles(R, t, world[:4], lookups[0], layout="tiles", tile_points=0)
