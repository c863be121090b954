"""rerender: a rollout of the object re-rendered through the static NeRF by ray bending."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.errors import FignetError, SettingError
from fignetctl.stages import check, device_setting, resolve_device, setting, write_summary


@dataclasses.dataclass(frozen=True)
class Settings:
    camera: int | None = setting(
        None, "Render from this view of --cameras (negative: from the end).", low=-(10**6), high=10**6
    )
    orbit: bool = setting(False, "Render from a camera circling the volume, one turn per --orbit-frames.")
    radius: float | None = setting(
        None,
        "Orbit radius, m.  [default: the cameras' median distance, else 4x the volume's diagonal]",
        low=1e-6,
        high=1e6,
    )
    elevation: float = setting(30.0, "Orbit elevation, degrees.", low=-89, high=89)
    orbit_frames: int | None = setting(
        None, "Frames per orbit turn.  [default: every output frame]", low=1, high=10**5
    )
    fov: float = setting(
        50.0, "Vertical field of view of an orbit without --cameras, degrees.", low=5, high=170
    )
    width: int | None = setting(
        None, "Image width (K is scaled).  [default: the camera's, or 320]", low=8, high=4096
    )
    height: int | None = setting(None, "Image height.  [default: keeps the aspect ratio]", low=8, high=4096)
    mode: str = setting(
        "move", "Move the object, or leave the original in place.", choices=("move", "duplicate")
    )
    object: str | None = setting(
        None, "Mesh name of the object in the rollout.  [default: the single dynamic object]"
    )
    trajectory: str | None = setting(None, "Trajectory id in the rollout file.  [default: the first]")
    every: int = setting(1, "Render every K-th rollout step.", low=1, high=10**5)
    fps: float | None = setting(
        None, "Video frame rate.  [default: real time, 1 / (dt * every)]", low=0.01, high=1000
    )
    trace: bool = setting(False, "Draw the object's path (its projected centre over time).")
    device: str = device_setting()


def default_frames_dir(video: Path) -> Path:
    """The PNG folder beside the mp4 `video`: its name without .mp4, plus _frames."""
    return video.with_name(video.stem + "_frames")


def camera_problem(settings: Settings, cameras_path) -> str | None:
    """What is wrong with the choice of camera (exactly one of a view of cameras.npz or an orbit)."""
    if settings.orbit == (settings.camera is not None):
        return "choose the camera with exactly one of --camera INDEX (with --cameras) or --orbit"
    if settings.camera is not None and cameras_path is None:
        return "--camera needs --cameras cameras.npz"
    return None


def run(
    nerf_path,
    volume_path,
    rollout_path,
    video,
    settings: Settings = Settings(),
    frames=None,
    cameras_path=None,
    rerun_path=None,
    json_path=None,
    progress=None,
) -> dict:
    """Re-render the rollout `rollout_path` of the object in the volume.npz `volume_path` through
    the NeRF `nerf_path`, from view `settings.camera` of `cameras_path` or an orbit: the mp4
    `video`, its PNG frames in the folder `frames` (default: `default_frames_dir`), optionally a
    rerun recording and the json summary. Returns the summary (frames, size, timings) with a
    one-line `message`."""
    from fignetctl.core import rerender as core
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.provenance import stamp
    from fignetctl.core.trajectory import read_trajectories
    from fignetctl.core.volume import read_volume

    check(settings)
    if problem := camera_problem(settings, cameras_path):
        raise SettingError(problem)
    video = Path(video)
    frames = Path(frames) if frames else default_frames_dir(video)
    volume = read_volume(volume_path)
    motion = core.object_motion(read_trajectories(rollout_path), volume, settings.trajectory, settings.object)
    steps = list(range(0, len(motion), settings.every))
    cameras = _cameras(cameras_path, settings, volume, len(steps))
    model = load_nerf(nerf_path, device=resolve_device(settings.device))
    renderer = core.Rerenderer(model, volume, motion, settings.mode)
    bar = (lambda items: progress(items, unit="frame", desc="rerender")) if progress else None
    fps = settings.fps or 1.0 / (motion.dt * settings.every)
    summary = write_rerender(renderer, cameras, steps, frames, video, fps, settings.trace, rerun_path, bar)
    message = (
        f"rendered {summary['frames']} frames {summary['width']}x{summary['height']} of {motion.name!r} "
        f"({settings.mode}): unedited render {summary['background_ms']:.0f} ms, {summary['frame_ms']:.0f} ms "
        f"per frame ({100 * summary['bent_fraction']:.1f} % of pixels bent); frames in {frames}"
    )
    provenance = stamp(nerf=nerf_path, volume=volume_path, rollout=rollout_path, cameras=cameras_path)
    summary = {"output": str(video), "frames_dir": str(frames), **summary}
    write_summary(json_path, summary, provenance)
    return {**summary, "message": message}


def _cameras(cameras_path, settings: Settings, volume, count):
    """One camera (K, c2w, width, height) per output frame."""
    import numpy as np

    from fignetctl.core import pinhole
    from fignetctl.core.cameras import read_cameras

    index, width, height = settings.camera, settings.width, settings.height
    cameras = read_cameras(cameras_path) if cameras_path else None
    if cameras is not None and index is not None and not -len(cameras) <= index < len(cameras):
        raise SettingError(
            f"--camera: camera {index} is out of range ({cameras_path} has {len(cameras)} views)"
        )
    native = (cameras.width, cameras.height) if cameras is not None else (320, 240)
    width = width or (native[0] if height is None else max(1, round(native[0] * height / native[1])))
    height = height or max(1, round(native[1] * width / native[0]))
    centre = 0.5 * (volume.lower + volume.upper)
    if cameras is None:
        K = pinhole.intrinsics_from_fov(width, height, settings.fov)
    else:
        K = pinhole.scale_intrinsics(cameras.K[index or 0], width / cameras.width, height / cameras.height)
    if not settings.orbit:
        return [pinhole.Camera(K, cameras.c2w[index], width, height)] * count
    radius = settings.radius
    if radius is None:
        radius = (
            float(np.median(np.linalg.norm(cameras.centres - centre, axis=1)))
            if cameras is not None
            else 4.0 * float(np.linalg.norm(volume.upper - volume.lower))
        )
    turn = pinhole.orbit(centre, radius, settings.elevation, settings.orbit_frames or count)
    return [pinhole.Camera(K, turn[i % len(turn)], width, height) for i in range(count)]


def write_rerender(
    renderer,
    cameras,
    steps,
    frames_dir,
    video_path,
    fps: float,
    trace=False,
    rerun_path=None,
    progress=None,
) -> dict:
    """Render `steps` through `renderer` (`core.rerender.Rerenderer`; one camera (K, c2w, width,
    height) per step in `cameras`) to frames_dir/frame_00000.png ... and an H.264 mp4
    (media.py), both atomically; optionally a rerun recording. Returns timings: background_ms
    (unedited render, per camera), frame_ms (mean per frame, bent pixels only), bent_fraction
    (mean share of bent pixels)."""
    import contextlib

    import cv2
    import numpy as np

    from fignetctl.core.atomic import atomic_directory, atomic_path
    from fignetctl.core.media import Mp4Writer
    from fignetctl.core.rerender import render_frames
    from fignetctl.core.rerun_log import recording

    steps, cameras = list(steps), list(cameras)
    width, height = int(cameras[0][2]), int(cameras[0][3])
    frame_seconds, bent_fractions = [], []
    with contextlib.ExitStack() as stack:
        tmp_dir = stack.enter_context(atomic_directory(frames_dir, ("frame_*.png",)))
        tmp_video = stack.enter_context(atomic_path(video_path, suffix=".mp4"))
        writer = stack.enter_context(Mp4Writer(tmp_video, float(fps), width, height))
        log = (
            _RerunLog(*stack.enter_context(recording(rerun_path)), renderer.motion, steps)
            if rerun_path
            else None
        )
        shots = progress(list(zip(steps, cameras))) if progress else zip(steps, cameras)
        for index, (step, camera, frame, image) in enumerate(render_frames(renderer, shots, trace)):
            frame_seconds.append(frame.seconds)
            bent_fractions.append(float(frame.bent.mean()))
            if not cv2.imwrite(
                str(tmp_dir / f"frame_{index:05d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            ):
                raise FignetError(f"{frames_dir}: OpenCV could not write a PNG")
            writer.write(image)
            if log:
                log.log(index, step, camera, image)
        writer.close()
        if log:
            log.video(tmp_video)
    return {
        "frames": len(steps),
        "width": width,
        "height": height,
        "background_ms": 1000.0 * float(np.mean(renderer.background_seconds)),
        "backgrounds": len(renderer.background_seconds),
        "frame_ms": 1000.0 * float(np.mean(frame_seconds)),
        "bent_fraction": float(np.mean(bent_fractions)),
    }


class _RerunLog:
    """Frames, camera and the object's path in a rerun recording (timeline "frame"), and the
    mp4 the frames went into."""

    def __init__(self, rr, rec, motion, steps):
        import numpy as np

        self.rr, self.rec = rr, rec
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        path_points = np.asarray(motion.positions[list(steps)], np.float32)
        self.rec.log(
            "world/trace", rr.LineStrips3D([path_points], colors=[(255, 210, 0)], radii=0.005), static=True
        )
        self.positions = motion.positions

    def log(self, index: int, step: int, camera, image) -> None:
        import numpy as np

        rr, rec = self.rr, self.rec
        K, c2w, width, height = camera
        rec.set_time("frame", sequence=index)
        rec.log("world/object", rr.Points3D([self.positions[step]], colors=[(255, 210, 0)], radii=0.02))
        rec.log("world/camera", rr.Transform3D(translation=c2w[:3, 3], mat3x3=c2w[:3, :3]))
        rec.log(
            "world/camera", rr.Pinhole(image_from_camera=np.asarray(K), width=int(width), height=int(height))
        )
        rec.log("world/camera/image", rr.Image(image))

    def video(self, path) -> int:
        """The H.264 mp4 itself (static at "video"), its frame k shown at frame k of the timeline;
        returns the number of frames rerun's decoder found in it."""
        import numpy as np

        rr = self.rr
        asset = rr.AssetVideo(path=path)
        self.rec.log("video", asset, static=True)
        timestamps = asset.read_frame_timestamps_nanos()
        self.rec.send_columns(
            "video",
            indexes=[rr.TimeColumn("frame", sequence=np.arange(len(timestamps)))],
            columns=rr.VideoFrameReference.columns_nanos(timestamps),
        )
        return len(timestamps)
