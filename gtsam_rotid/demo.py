"""``gtsam-rotid demo`` (the command-line layer): the whole pipeline on a shortened reference scene: simulate the
arm poses, render each spin (:mod:`gtsam_rotid.pixels`), track, calibrate, print the result and its true error, and
write the dataset, the result and one overlay picture per measurement (the paper's "quad view",
:func:`gtsam_rotid.plots.plot_overlay`).
"""

from __future__ import annotations

import builtins
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError, OutputError, OutputExistsError, RotIdError
from .files import OVERWRITE_HINT, check_outputs, write_text
from .meshrender import MeshRenderConfig
from .pixels import VideoScene, dataset_from_video
from .render import RenderConfig
from .tracking import TrackerParams
from .words import summary

#: Seconds of wrist spin per measurement in :func:`run_demo` (the reference scene has 60 s): with six
#: measurements the demo renders and tracks 3600 frames and takes well under two minutes on two cores.
DEMO_DURATION = 20.0
#: What covers the hand in the demo's mesh rendering (:data:`gtsam_rotid.meshrender.COVERINGS`).
DEMO_COVERING = "dots"
#: Arm poses drawn beyond those wanted for the mesh renderer: the simulator's pose sampler knows no meshes, so the
#: demo keeps the first poses whose every spin it can render (the first poses are the same however many are drawn).
DEMO_SPARE_POSES = 6
DATASET_DIR = "dataset"
TRUTH_FILE = "truth.json"
RESULT_FILE = "result.json"
TRACKING_FILE = "tracking.txt"


# ---------------------------------------------------------------------------------------------- demo
@dataclass
class DemoRun:
    """What :func:`run_demo` returns: the simulated ``truth``, the tracked ``scene``, the calibration
    ``result``, the files written (``paths``) and the wall time of each step (seconds)."""

    truth: object
    scene: VideoScene
    result: object
    paths: list[Path] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)


def demo_files(out_dir: str | os.PathLike, n_measurements: int) -> dict[str, Path | list[Path]]:
    """The files :func:`run_demo` writes into ``out_dir``."""
    from .plots import overlay_files

    out = Path(out_dir)
    return {"dataset": out / DATASET_DIR, "result": out / RESULT_FILE, "tracking": out / TRACKING_FILE,
            "overlays": overlay_files(out, range(n_measurements))}


def _check_demo_output(out: Path, n_measurements: int, overwrite: bool) -> None:
    """Refuse before the slow work, not after."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out} exists and is not a directory")
    files = demo_files(out, n_measurements)
    if files["dataset"].exists() and not overwrite:
        raise OutputExistsError(f"{files['dataset']} exists; {OVERWRITE_HINT}")
    if out.is_dir():
        check_outputs([files["result"], files["tracking"], *files["overlays"]], overwrite)


def demo_render_config(renderer: str = "mesh", covering: str | None = None,
                       seed: int = 0) -> RenderConfig | MeshRenderConfig:
    """The demo's rendering: ``"mesh"`` (the robot's own meshes, the hand covered by ``covering``, default
    :data:`DEMO_COVERING`) or ``"cylinder"`` (the dotted stepped cylinder of :mod:`gtsam_rotid.render`)."""
    if renderer == "cylinder":
        return RenderConfig()
    if renderer != "mesh":
        raise InputError(f"renderer must be 'mesh' or 'cylinder', got {renderer!r}")
    return MeshRenderConfig(covering=DEMO_COVERING if covering is None else covering, seed=seed)


def run_demo(out_dir: str | os.PathLike | None = None, *, seed: int = 0, duration: float = DEMO_DURATION,
             n_measurements: int = 6, method: str = "joint",
             render_config: RenderConfig | MeshRenderConfig | None = None,
             tracker_params: TrackerParams | None = None, overwrite: bool = False, progress: bool = True,
             spin_joints: tuple[str, ...] = (), print: Callable[..., None] = builtins.print) -> DemoRun:
    """The whole pixel pipeline on the reference scene (seed ``seed``, ``n_measurements`` spins of ``duration``
    s): simulate the arm poses, render each spin, track it, calibrate with ``method``, and print the result and
    its error against the truth.

    ``spin_joints``: spin each of these joints at every arm pose, one measurement each (default: the wrist alone;
    :class:`gtsam_rotid.simulate.SceneConfig`). With the mesh renderer, an arm pose with a spin it cannot render (see
    :func:`gtsam_rotid.meshrender.pose_problem`: the hand leaves the image or hides behind the arm over a whole turn)
    is skipped, named, for the next of ``DEMO_SPARE_POSES`` spare poses. With ``out_dir`` the tracked dataset is
    written before the calibration, so that a calibration that fails leaves it for ``gtsam-rotid calibrate``.

    With ``out_dir``: also write ``dataset/`` (the tracked dataset, with ``truth.json``), ``result.json``,
    ``tracking.txt`` (the tracking summary and its accuracy against the rendered truth) and one
    ``overlay_m{k}.png`` per measurement (the quad view of :func:`gtsam_rotid.plots.plot_overlay` on the frame
    with the most tracked points). Existing files are refused before any work unless ``overwrite``.
    ``print`` receives every line of output (progress bars go to stderr when ``progress``).
    """
    from . import simulate  # the estimator on first use: ``gtsam-rotid --help`` need not load it
    from .calibration import calibrate
    from .report import error_vs_truth_lines

    clock = time.perf_counter()
    seconds: dict[str, float] = {}
    out = None if out_dir is None else Path(out_dir)
    spin_joints = tuple(spin_joints or ())
    if out is not None:
        _check_demo_output(out, n_measurements * max(len(spin_joints), 1), overwrite)
    render_config = demo_render_config(seed=seed) if render_config is None else render_config
    drawn = (f"the robot's own meshes, the hand covered by {render_config.covering}"
             if isinstance(render_config, MeshRenderConfig) else "a dotted cylinder for the hand")
    start = time.perf_counter()
    mesh = isinstance(render_config, MeshRenderConfig)
    simulated, truth = simulate.reference_scene(seed=seed, duration=duration, spin_joints=spin_joints,
                                                n_measurements=n_measurements + (DEMO_SPARE_POSES if mesh else 0))
    spins = (f"wrist spins of {duration:g} s" if not spin_joints
             else f"arm poses, each spinning {', '.join(spin_joints)} for {duration:g} s")
    print(f"gtsam-rotid demo from pixels: the reference scene (Kinova Jaco2, Xtion-like camera), seed {seed}, "
          f"{n_measurements} {spins}, rendered, tracked and calibrated ({drawn})")
    if mesh:
        simulated, truth = _renderable(simulated, truth, render_config, print, max(len(spin_joints), 1),
                                       n_measurements)
    seconds["simulate"] = time.perf_counter() - start
    T = truth.arm_T_camera
    x, y, z = T.translation() * 1000.0
    r, p, yaw = np.degrees(T.rotation().rpy())
    print(f"true arm_T_camera: t = ({x:.1f}, {y:.1f}, {z:.1f}) mm, rpy = ({r:.2f}, {p:.2f}, {yaw:.2f}) deg")
    print("rendering and tracking...", flush=True)
    scene = dataset_from_video(simulated, truth, render_config, tracker_params, progress=progress)
    seconds["render"], seconds["track"] = scene.render_seconds, scene.track_seconds
    print(scene.summary())
    paths: list[Path] = []
    if out is not None:  # (before calibrating: minutes of rendering and tracking are not lost if it fails)
        start = time.perf_counter()
        paths = _write_tracked(out, scene, truth, overwrite)
        seconds["write"] = time.perf_counter() - start
        for path in paths:
            print(f"wrote {path}")
    print(f"calibrating ({method})...", flush=True)
    start = time.perf_counter()
    try:
        result = calibrate(scene.dataset, method=method)
    except RotIdError:
        if out is not None:
            print(f"the tracked dataset is kept in {paths[0]} (gtsam-rotid calibrate {paths[0]})")
        raise
    seconds["calibrate"] = time.perf_counter() - start
    print(f"calibrated in {seconds['calibrate']:.1f} s")
    print(summary(result))
    for line in error_vs_truth_lines(result, truth.arm_T_camera):
        print(line)
    if out is not None:
        start = time.perf_counter()
        written = _write_result(out, scene, result, overwrite)
        seconds["write"] += time.perf_counter() - start
        for path in written:
            print(f"wrote {path}")
        paths += written
    seconds["total"] = time.perf_counter() - clock
    print(f"demo took {seconds['total']:.1f} s")
    return DemoRun(truth, scene, result, paths, seconds)


def _renderable(simulated, truth, config: MeshRenderConfig, print: Callable[..., None], per_pose: int = 1,
                wanted: int | None = None):
    """The first ``wanted`` (default all) arm poses of the simulated scene (``per_pose`` spins at each, in order)
    whose every spin the mesh renderer can render; each pose skipped is named, with why. Raises InputError where
    fewer than MIN_MEASUREMENTS poses are left."""
    from dataclasses import replace

    from .calibration.options import MIN_MEASUREMENTS
    from .dataset import Dataset
    from .meshrender import load_arm_meshes, pose_problem

    meshes = load_arm_meshes(simulated.arm)
    n_poses = len(simulated) // per_pose
    wanted = n_poses if wanted is None else wanted
    kept: list[int] = []
    for pose in range(n_poses):
        if len(kept) == wanted:
            break
        for k in range(pose * per_pose, (pose + 1) * per_pose):
            m = simulated[k]
            problem = pose_problem(simulated.arm, simulated.camera, truth.arm_T_camera, m.joint_angles, config,
                                   meshes=meshes, spin_joint=m.spin_joint)
            if problem is not None:
                joint = simulated.arm.joint_names[simulated.arm.spin_index(m.spin_joint)]
                print(f"arm pose {pose} is skipped: the mesh renderer cannot render its spin of {joint}: {problem}")
                break
        else:
            kept.append(pose)
    if len(kept) < wanted:
        print(f"only {len(kept)} of {n_poses} arm poses drawn can be rendered")
    if len(kept) < MIN_MEASUREMENTS:
        raise InputError(f"the mesh renderer can render {len(kept)} arm pose(s) of this scene, fewer than "
                         f"{MIN_MEASUREMENTS} (see above); try another --seed or the cylinder renderer")
    if kept == list(range(n_poses)):
        return simulated, truth
    rows = [k for pose in kept for k in range(pose * per_pose, (pose + 1) * per_pose)]
    dataset = Dataset(simulated.arm, simulated.camera, [simulated[k] for k in rows], metadata=simulated.metadata)
    return dataset, replace(truth, measurements=[truth.measurements[k] for k in rows],
                            config={**truth.config, "rendered_poses": kept})


def _write_tracked(out: Path, scene: VideoScene, truth, overwrite: bool) -> list[Path]:
    """The tracked dataset (with the truth) and the tracking summary: written before the calibration."""
    files = demo_files(out, len(scene.dataset))
    out.mkdir(parents=True, exist_ok=True)
    scene.dataset.save(files["dataset"], overwrite=overwrite)
    truth.save(files["dataset"] / TRUTH_FILE, overwrite=True)
    parts = [scene.summary()] + [f"measurement {k}: {r.summary()}" for k, r in enumerate(scene.tracking)]
    write_text(files["tracking"], "\n\n".join(parts) + "\n", overwrite)
    return [files["dataset"], files["tracking"]]


def _write_result(out: Path, scene: VideoScene, result, overwrite: bool) -> list[Path]:
    """The calibration's result and one overlay picture per measurement."""
    from .plots import save_overlays  # matplotlib only when writing

    files = demo_files(out, len(scene.dataset))
    result.save(files["result"], overwrite=overwrite)
    frames = {}
    for k, spin in enumerate(scene.spins):
        position = scene.busiest_frame(k)
        frames[k] = (int(spin.frame_indices[position]), spin.frame(position))
    overlays = save_overlays(result, scene.dataset, frames, out, overwrite=overwrite)
    return [files["result"], *overlays]
