"""The picture of extract-mesh in the docs: each prompted view of the main job's object, cropped
around it and enlarged, with the edge of its mask (green) and the outline of the extracted mesh
(magenta).

    python benchmarks/extract_mesh_strip.py out/scene -o docs/images/extract-mesh-strip.png
"""

import argparse
from pathlib import Path

import cv2
import numpy as np

GREEN, MAGENTA = (40, 200, 60), (230, 40, 220)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="the main job's output folder (out/scene)")
    parser.add_argument("--scale", type=int, default=3, help="each crop is enlarged this many times")
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args()
    import trimesh

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.mesh_extraction import View, silhouette
    from fignetctl.core.obj import read_obj
    from fignetctl.core.volume import read_volume

    folder = args.scene / "object"
    needed = [folder / "object.obj", folder / "volume.npz", args.scene / "cameras.npz"]
    missing = [str(p) for p in needed if not p.is_file()]
    if missing:
        raise SystemExit(f"error: missing {', '.join(missing)}; run `make demo` first")
    cameras = read_cameras(args.scene / "cameras.npz")
    volume = read_volume(folder / "volume.npz")
    mesh = trimesh.Trimesh(*read_obj(folder / "object.obj"))
    mesh.apply_translation(volume.origin)
    tiles = []
    for mask_path in sorted((folder / "masks").glob("*.png")):
        index = cameras.index_of(mask_path.name)
        image = cv2.imread(str(args.scene / "capture" / "images" / mask_path.name))
        mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE) > 0
        view = View(mask_path.name, cameras.K[index], cameras.c2w[index], np.zeros(mask.shape))
        outline = silhouette(mesh.vertices, mesh.faces, view, mask.shape)
        rows, columns = np.nonzero(mask | outline)
        pad = max(8, (rows.max() - rows.min()) // 2)
        top, left = max(rows.min() - pad, 0), max(columns.min() - pad, 0)
        bottom, right = rows.max() + pad + 1, columns.max() + pad + 1
        crop = cv2.resize(
            image[top:bottom, left:right], None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_NEAREST
        )
        for shape, colour in ((mask, GREEN), (outline, MAGENTA)):
            big = cv2.resize(
                shape[top:bottom, left:right].astype(np.uint8),
                None,
                fx=args.scale,
                fy=args.scale,
                interpolation=cv2.INTER_NEAREST,
            )
            contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(crop, contours, -1, colour[::-1], 2)
        cv2.putText(crop, mask_path.stem, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        tiles.append(crop)
    if not tiles:
        raise SystemExit(f"error: no masks in {folder / 'masks'}; extract the object with prompts first")
    height = max(tile.shape[0] for tile in tiles)
    tiles = [cv2.copyMakeBorder(t, 0, height - t.shape[0], 0, 4, cv2.BORDER_CONSTANT) for t in tiles]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.output), np.concatenate(tiles, axis=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
