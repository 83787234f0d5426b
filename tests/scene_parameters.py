"""Parameters of the session scenes in conftest.py that tests read too (one place, so a scene and what its tests
expect of it cannot drift apart)."""

#: the ``demo`` run shared by test_pixels.py and test_demo.py: four 8 s spins of the reference scene (~1000 frames)
DEMO_N_MEASUREMENTS, DEMO_DURATION = 4, 8.0
#: pixel noise variance (px^2) of ``reference_8s_weighted`` (the reference scene, seed 1, 8 s spins), shared by
#: test_plots.py and test_fits.py
REFERENCE_8S_NOISE_VAR = 1.5
