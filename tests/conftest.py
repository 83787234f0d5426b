"""Scenes shared by several test modules, built once per session (results are not mutated by the tests)."""

import os

# One BLAS/OpenMP thread per process (unless set): the suite's small matrices gain nothing from threads, and the
# tests that run joblib or Dask workers on both cores otherwise oversubscribe them (a fresh-clone run took 19.8 min
# with the libraries' default threads, 17.7 min with one thread and another job beside it). Set before numpy loads.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import pytest  # noqa: E402
from scene_parameters import DEMO_DURATION, DEMO_N_MEASUREMENTS, REFERENCE_8S_NOISE_VAR  # noqa: E402

from gtsam_rotid import simulate  # noqa: E402
from gtsam_rotid.calibration import calibrate  # noqa: E402
from gtsam_rotid.demo import run_demo  # noqa: E402
from gtsam_rotid.render import RenderConfig  # noqa: E402


@pytest.fixture(scope="session")
def reference_weighted():
    """The reference scene (seed 0, 10 s spins) and its ``weighted`` calibration: (dataset, truth, result)."""
    dataset, truth = simulate.reference_scene(seed=0, duration=10.0)
    return dataset, truth, calibrate(dataset, method="weighted")


@pytest.fixture(scope="session")
def reference_8s_weighted():
    """The reference scene (seed 1, 8 s spins, scene_parameters.REFERENCE_8S_NOISE_VAR) and its ``weighted``
    calibration: (dataset, truth, result). Read by test_plots.py and test_fits.py."""
    dataset, truth = simulate.reference_scene(seed=1, duration=8.0, noise_var=REFERENCE_8S_NOISE_VAR)
    return dataset, truth, calibrate(dataset, method="weighted")


@pytest.fixture(scope="session")
def noise_free_scene():
    """Five noise-free 6 s spins of the reference scene (seed 1): (dataset, truth)."""
    return simulate.reference_scene(seed=1, noise_var=0.0, duration=6.0, n_measurements=5)


@pytest.fixture(scope="session")
def noisy_scene():
    """The reference scene at 1.5 px^2 pixel noise, six 12 s spins (seed 11): (dataset, truth)."""
    return simulate.reference_scene(seed=11, noise_var=1.5, duration=12.0)


@pytest.fixture(scope="session")
def single_crossing():
    """Noise-free 6 s spins whose wrist axes all pass through one point (seed 0): (dataset, truth)."""
    return simulate.single_crossing_scene(seed=0, noise_var=0.0, duration=6.0)


@pytest.fixture(scope="session")
def demo(tmp_path_factory):
    """One short rendered scene (scene_parameters.DEMO_*) run through ``run_demo``: (output directory, DemoRun,
    printed text). Read by test_pixels.py and test_demo.py."""
    out = tmp_path_factory.mktemp("demo")
    lines: list[str] = []
    run = run_demo(out, duration=DEMO_DURATION, n_measurements=DEMO_N_MEASUREMENTS, progress=False,
                   render_config=RenderConfig(),  # the dotted cylinder, whose dots are matched to their true centres
                   print=lambda *args, **kwargs: lines.append(" ".join(str(a) for a in args)))
    return out, run, "\n".join(lines)
