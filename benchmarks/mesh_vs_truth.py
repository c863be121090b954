"""An extract-mesh output against a capture's ground truth.

The capture is in render-views' layout (render-views' own, or benchmarks/foreign_capture.py's):
prompts.json (each object's id, name and prompted views) and ground_truth/ with cameras.npz,
masks.npz (per-view object ids) and objects/NAME.obj. The extract-mesh folder holds object.obj,
volume.npz and masks/. The true mesh is moved into the frame of `cameras` (the cameras the
NeRF was fitted with, e.g. capture-poses') by the similarity that best maps the true camera
centres onto theirs (Umeyama), so sizes are compared in the same units.

    .venv/bin/python benchmarks/mesh_vs_truth.py out/scene/capture out/scene/cameras.npz out/scene/object

Prints one json object per line (or writes a list with --json): per prompted view the IoU of
the mask extract-mesh used against the true mask; the mesh's axis-aligned size over the true
mesh's per axis; the symmetric Chamfer distance as % of the true mesh's largest side; the mesh's
volume over the true volume (when both are closed); whether it meets issue 18's bar (each axis
within 10 % and Chamfer <= 5 %).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def truth_to(cameras, truth_cameras) -> np.ndarray:
    """(4, 4) similarity from the true frame into the frame of `cameras` (views matched by name)."""
    from fignetctl.core.world_alignment import umeyama

    names = [str(n) for n in cameras.image_names if n in set(truth_cameras.image_names)]
    source = np.stack([truth_cameras.c2w[truth_cameras.index_of(n)][:3, 3] for n in names])
    target = np.stack([cameras.c2w[cameras.index_of(n)][:3, 3] for n in names])
    scale, rotation, translation = umeyama(source, target)
    matrix = np.eye(4)
    matrix[:3, :3] = scale * rotation
    matrix[:3, 3] = translation
    return matrix


def chamfer(mesh, truth, samples=20000, seed=0) -> float:
    """Symmetric mean closest-point distance between surface samples of both meshes."""
    from scipy.spatial import cKDTree

    a = mesh.sample(samples, seed=seed)
    b = truth.sample(samples, seed=seed)
    return 0.5 * float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


def mask_ious(capture, folder, obj) -> dict:
    """{prompted view: IoU of folder/masks/VIEW.png with the true mask of `obj`} (views with a mask)."""
    import cv2

    from fignetctl.core.cameras import read_cameras

    truth_masks = np.load(capture / "ground_truth" / "masks.npz")["masks"]
    names = [str(n) for n in read_cameras(capture / "ground_truth" / "cameras.npz").image_names]
    ious = {}
    for point in obj["points"]:
        path = Path(folder) / "masks" / (Path(point["image"]).stem + ".png")
        if path.exists():
            mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 0
            true = truth_masks[names.index(point["image"])] == obj["id"]
            ious[point["image"]] = round(float((mask & true).sum() / max((mask | true).sum(), 1)), 3)
    return ious


def compare(capture, cameras_path, folder, name=None) -> dict:
    """The figures above for the object `name` of prompts.json (default: the first) meshed in `folder`."""
    import trimesh

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.volume import read_volume

    capture, folder = Path(capture), Path(folder)
    objects = json.loads((capture / "prompts.json").read_text())["objects"]
    obj = next(o for o in objects if name in (None, o["name"]))
    truth = trimesh.load(capture / "ground_truth" / "objects" / f"{obj['name']}.obj", force="mesh")
    truth.apply_transform(
        truth_to(read_cameras(cameras_path), read_cameras(capture / "ground_truth" / "cameras.npz"))
    )
    volume = read_volume(folder / "volume.npz")
    mesh = trimesh.load(folder / volume.object_mesh, force="mesh", process=False)
    mesh.apply_translation(volume.origin)
    ratio = mesh.extents / truth.extents
    entry = {
        "object": obj["name"],
        "mask_iou": mask_ious(capture, folder, obj),
        "size": mesh.extents.round(4).tolist(),
        "true_size": truth.extents.round(4).tolist(),
        "size_ratio_xyz": ratio.round(3).tolist(),
        "chamfer_pct_of_size": round(100 * chamfer(mesh, truth) / float(truth.extents.max()), 2),
        "watertight": bool(mesh.is_watertight),
        "volume_ratio": (
            round(float(mesh.volume / truth.volume), 3)
            if mesh.is_watertight and truth.is_watertight
            else None
        ),
    }
    entry["meets_bar"] = bool(np.all(np.abs(ratio - 1) <= 0.10) and entry["chamfer_pct_of_size"] <= 5.0)
    return entry


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path, help="render-views' folder (prompts.json, ground_truth/)")
    parser.add_argument("cameras", type=Path, help="cameras.npz the NeRF was fitted with")
    parser.add_argument("folders", type=Path, nargs="+", help="extract-mesh output folders")
    parser.add_argument("--object", action="append", help="the object of each folder (default: the first)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    names = args.object or [None] * len(args.folders)
    if len(names) != len(args.folders):
        parser.error("give one --object per folder, or none")
    results = [compare(args.capture, args.cameras, f, n) for f, n in zip(args.folders, names)]
    for entry in results:
        print(json.dumps(entry))
    if args.json:
        from fignetctl.core.atomic import write_json

        write_json(args.json, results)


if __name__ == "__main__":
    main()
