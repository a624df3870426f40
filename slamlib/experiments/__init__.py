"""Experiment tooling around the 3D filter: what runs the filter over many drives and shows what it built.

The filter (:mod:`slamlib.slam3d`) registers frames; this package uses it together with the synthetic-data
generator (:mod:`slamlib.synth`), and the filter never imports it:

* :mod:`~slamlib.experiments.sweep`: sweeps of SLAM (and KISS-ICP) over routes x seeds x settings on synthetic
  drives, as tasks on a Dask cluster, into one tidy table (``slamlib sweep``);
* :mod:`~slamlib.experiments.video`: a video of the map being built, from a run's snapshots (``slamlib run
  --video``);
* :mod:`~slamlib.experiments.render`: 3D pictures of a map with its trajectory (open3d offscreen, or matplotlib).

Layering (CONTRIBUTING.md, ``tests/test_layers.py``): ``commands`` -> ``experiments`` -> ``slam3d``, ``synth``.
The submodules are imported by name (``from slamlib.experiments.sweep import run_sweep``); this package imports
none of them, so importing one does not load the others' optional dependencies.
"""
