"""Readers given truncated or corrupted files end in FormatError, never another exception."""

import numpy as np
import pytest

from fignetctl.core.model.checkpoint import load_checkpoint, save_checkpoint
from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.scene_graph import GraphConfig
from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.errors import FignetError, FormatError
from tests.conftest import box_drop_file


def _damaged_copies(original: bytes, rng, count):
    """Truncations at random lengths and copies with random bytes overwritten."""
    for _ in range(count):
        cut = int(rng.integers(0, len(original)))
        yield original[:cut]
        damaged = np.frombuffer(original, np.uint8).copy()
        spots = rng.integers(0, len(original), size=int(rng.integers(1, 64)))
        damaged[spots] = rng.integers(0, 256, size=len(spots), dtype=np.uint8)
        yield damaged.tobytes()


def _accepts_or_refuses_clearly(reader, path):
    try:
        reader(path)
    except FormatError as error:
        assert str(error).startswith(str(path)) and "\n" not in str(error)


def test_trajectory_reader_on_damaged_files(tmp_path):
    original = write_trajectories(tmp_path / "t.h5", box_drop_file(frames=6), compression=None).read_bytes()
    rng = np.random.default_rng(0)
    for index, content in enumerate(_damaged_copies(original, rng, 60)):
        path = tmp_path / f"damaged-{index}.h5"
        path.write_bytes(content)
        _accepts_or_refuses_clearly(read_trajectories, path)


def test_model_reader_on_damaged_files(tmp_path):
    simulator = LearnedSimulator(SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1)))
    original = save_checkpoint(tmp_path / "m.pt", simulator).read_bytes()
    rng = np.random.default_rng(1)
    for index, content in enumerate(_damaged_copies(original, rng, 40)):
        path = tmp_path / f"damaged-{index}.pt"
        path.write_bytes(content)
        _accepts_or_refuses_clearly(load_checkpoint, path)


@pytest.mark.parametrize("content", [b"", b"\x00" * 10, b"PK\x03\x04" + b"\x00" * 100])
def test_tiny_garbage_is_refused(tmp_path, content):
    for reader, suffix in ((read_trajectories, ".h5"), (load_checkpoint, ".pt")):
        path = tmp_path / f"garbage{suffix}"
        path.write_bytes(content)
        with pytest.raises(FormatError):
            reader(path)


# --- Damage that the HDF5 C library does not survive (found by fuzzing seeds 2, 162, 210) ---


def _global_heap_free_space_emptied(original: bytes) -> bytes:
    """The free-space object of the first global heap collection given size 0: HDF5 2.0 then
    loops forever while reading the 'format' attribute (the fuzzing seed-2 hang)."""
    data = bytearray(original)
    start = data.index(b"GCOL")
    end = start + int.from_bytes(data[start + 8 : start + 16], "little")
    position = start + 16
    while position + 16 <= end:
        index = int.from_bytes(data[position : position + 2], "little")
        size = int.from_bytes(data[position + 8 : position + 16], "little")
        if index == 0:
            data[position + 8 : position + 16] = bytes(8)
            return bytes(data)
        position += 16 + (size + 7) // 8 * 8
    raise AssertionError("no free space in the global heap")


def _string_type_damaged(original: bytes) -> bytes:
    """The 'format' attribute's variable-length string datatype given an invalid kind: HDF5
    2.0 then crashes with a segmentation fault reading it (the fuzzing seed-162 crash)."""
    data = bytearray(original)
    message = data.index(b"format\x00\x00\x19\x01") + 8
    data[message + 1] = 0xA9
    return bytes(data)


@pytest.mark.parametrize("damage", [_global_heap_free_space_emptied, _string_type_damaged])
def test_damage_that_stops_the_hdf5_library_is_refused(tmp_path, damage):
    original = write_trajectories(tmp_path / "t.h5", box_drop_file(frames=6), compression=None).read_bytes()
    path = tmp_path / "damaged.h5"
    path.write_bytes(damage(original))
    with pytest.raises(FormatError, match="damaged"):
        read_trajectories(path)


def test_trajectory_reader_on_more_damage_patterns(tmp_path):
    """Bit flips, zeroed runs and 0xff runs on plain and gzip files (seeds beside the above)."""
    rng = np.random.default_rng(7)
    for compression in (None, "gzip"):
        original = write_trajectories(
            tmp_path / "t.h5", box_drop_file(frames=6), compression=compression
        ).read_bytes()
        for index in range(40):
            damaged = np.frombuffer(original, np.uint8).copy()
            start = int(rng.integers(0, len(original)))
            kind = index % 3
            if kind == 0:
                spots = rng.integers(0, len(original), size=4)
                damaged[spots] ^= (1 << rng.integers(0, 8, size=4)).astype(np.uint8)
            else:
                damaged[start : start + int(rng.integers(1, 64))] = 0 if kind == 1 else 255
            path = tmp_path / f"damaged-{compression}-{index}.h5"
            path.write_bytes(damaged.tobytes())
            _accepts_or_refuses_clearly(read_trajectories, path)


# --- Other readers: damaged copies and wrong-but-valid containers ---


def _refuses_clearly(reader, path, error=FignetError):
    with pytest.raises(error) as caught:
        reader(path)
    assert "\n" not in str(caught.value)


def _cameras_file(path):
    from fignetctl.core.cameras import Cameras, write_cameras

    c2w = np.tile(np.eye(4), (8, 1, 1))
    c2w[:, :3, 3] = np.arange(24).reshape(8, 3)
    K = np.tile(np.array([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]), (8, 1, 1))
    names = np.array([f"v{i}.png" for i in range(8)])
    write_cameras(path, Cameras(names, K, c2w, 64, 48, np.zeros((5, 3)), np.zeros((5, 3), np.uint8)))
    return path


def _volume_file(path):
    from fignetctl.core.volume import Volume, write_volume

    return write_volume(path, Volume(np.zeros(3), np.ones(3), np.full(3, 0.5), -np.ones(3), 2 * np.ones(3)))


def _nerf_file(path):
    from fignetctl.core.nerf.config import NerfConfig
    from fignetctl.core.nerf.io import save_nerf
    from fignetctl.core.nerf.model import NerfModel

    config = NerfConfig(
        grid_resolution_initial=8, grid_resolution=8, feature_resolution=8, feature_channels=4, mlp_width=8
    )
    return save_nerf(path, NerfModel(config, [[-1, -1, -1], [1, 1, 1]]))


def _obj_file(path):
    import trimesh

    trimesh.creation.box().export(path)
    return path


def _readers():
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.obj import load_obj
    from fignetctl.core.volume import read_volume

    return {
        "cameras.npz": (read_cameras, _cameras_file),
        "volume.npz": (read_volume, _volume_file),
        "nerf.pt": (load_nerf, _nerf_file),
        "box.obj": (load_obj, _obj_file),
    }


@pytest.mark.parametrize("name", ["cameras.npz", "volume.npz", "nerf.pt", "box.obj"])
def test_other_readers_on_damaged_and_foreign_files(tmp_path, name):
    readers = _readers()
    reader, make = readers[name]
    original = make(tmp_path / name).read_bytes()
    rng = np.random.default_rng(3)
    for index, content in enumerate(_damaged_copies(original, rng, 25)):
        path = tmp_path / f"damaged-{index}-{name}"
        path.write_bytes(content)
        try:
            reader(path)
        except FignetError as error:
            assert "\n" not in str(error)
    for other, (_, make_other) in readers.items():
        if other != name and name != "box.obj":
            _refuses_clearly(reader, make_other(tmp_path / f"foreign-{other}"))


def _npz_with(tmp_path, make, name, **changes):
    good = dict(np.load(make(tmp_path / f"good-{name}")))
    path = tmp_path / f"changed-{name}"
    np.savez(path, **{**good, **changes})
    return path


@pytest.mark.parametrize(
    "changes",
    [
        {"K": np.array([["a"] * 3] * 3)},
        {"K": np.zeros((8, 3, 3)) + 1j},
        {"points": np.arange(4.0)},
        {"point_colors": np.array(["x"] * 5)},
        {"format_version": np.array("1")},
        {"format_version": np.array(1.5)},
        {"width": np.arange(3)},
        {"width": np.array("wide")},
        {"c2w": np.full((8, 4, 4), np.nan)},
    ],
)
def test_cameras_npz_with_wrong_fields(tmp_path, changes):
    from fignetctl.core.cameras import read_cameras

    _refuses_clearly(read_cameras, _npz_with(tmp_path, _cameras_file, "cameras.npz", **changes), FormatError)


@pytest.mark.parametrize(
    "changes",
    [
        {"lower": np.array(["a", "b", "c"])},
        {"lower": np.zeros(3) + 1j},
        {"settings": np.array("[1, 2]")},
        {"settings": np.array("{")},
        {"object_mesh": np.zeros((2, 2))},
        {"environment_origin": np.array("x")},
        {"format_version": np.array("1")},
        {"origin": np.zeros(4)},
        {"object_mesh": np.array("../../etc/passwd")},
        {"environment_mesh": np.array("/tmp/other.obj")},
        {"object_mesh": np.array("sub/object.obj")},
        {"object_mesh": np.array("..")},
    ],
)
def test_volume_npz_with_wrong_fields(tmp_path, changes):
    from fignetctl.core.volume import read_volume

    _refuses_clearly(read_volume, _npz_with(tmp_path, _volume_file, "volume.npz", **changes), FormatError)


@pytest.mark.parametrize(
    "changes",
    [
        {"config": "{"},
        {"config": "[1]"},
        {"config": {"a": 1}},
        {"bounds": [[0, 0], [1, 1]]},
        {"bounds": [[1, 1, 1], [-1, -1, -1]]},
        {"bounds": [[float("nan")] * 3, [1] * 3]},
        {"density_shape": [-1, 8, 8]},
        {"density_shape": [800, 800, 800]},
        {"model": {}},
        {"metrics": "{"},
    ],
)
def test_nerf_file_with_wrong_fields(tmp_path, changes):
    import torch

    from fignetctl.core.nerf.io import load_nerf

    payload = torch.load(_nerf_file(tmp_path / "nerf.pt"), weights_only=True)
    torch.save({**payload, **changes}, tmp_path / "changed.pt")
    _refuses_clearly(load_nerf, tmp_path / "changed.pt", FormatError)


def test_model_file_with_wrong_fields(tmp_path):
    import torch

    simulator = LearnedSimulator(SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1)))
    payload = torch.load(save_checkpoint(tmp_path / "m.pt", simulator), weights_only=True)
    nan_weights = {
        k: torch.full_like(v, float("nan")) if v.is_floating_point() else v
        for k, v in payload["model"].items()
    }
    for index, changes in enumerate(
        [
            {"simulator_config": "{"},
            {"simulator_config": "[1]"},
            {"simulator_config": {"a": 1}},
            {"simulator_config": payload["simulator_config"].replace("0.1", "NaN")},
            {"model": {}},
            {"model": torch.zeros(3)},
            {"model": nan_weights},
        ]
    ):
        torch.save({**payload, **changes}, tmp_path / f"changed-{index}.pt")
        _refuses_clearly(load_checkpoint, tmp_path / f"changed-{index}.pt", FormatError)
    torch.save({**payload, "training_state": "garbage"}, tmp_path / "state.pt")
    _refuses_clearly(
        lambda p: load_checkpoint(p, with_training_state=True), tmp_path / "state.pt", FormatError
    )
    _refuses_clearly(load_checkpoint, _nerf_file(tmp_path / "nerf.pt"), FormatError)


_TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.mark.parametrize(
    "text",
    [
        "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "v 1e300 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        _TRIANGLE + "f 1 2 9\n",
        _TRIANGLE + "f -1 -2 -7\n",
        _TRIANGLE,
        "",
        "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
        "v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n",
        "hello world\nf a b c\n",
        "v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n",
        "\x00\xff\xfe" * 100,
    ],
)
def test_obj_that_is_no_usable_mesh(tmp_path, text):
    from fignetctl.core.obj import load_obj

    path = tmp_path / "bad.obj"
    path.write_bytes(text.encode("latin-1"))
    _refuses_clearly(load_obj, path)


def test_obj_with_holes_and_some_zero_area_faces_is_read(tmp_path):
    """An open box (a hole) with one extra zero-area face is a usable mesh: it is read as is."""
    import trimesh

    from fignetctl.core.obj import load_obj

    box = trimesh.creation.box()
    faces = np.vstack([box.faces[2:], [[0, 0, 1]]])
    trimesh.Trimesh(box.vertices, faces, process=False).export(tmp_path / "open.obj")
    mesh = load_obj(tmp_path / "open.obj")
    assert len(mesh.faces) == len(faces) and np.all(np.isfinite(mesh.vertices))


@pytest.mark.parametrize(
    "document",
    [
        [1, 2],
        {"format": "fignetctl.prompts", "format_version": 1, "objects": {"a": 1}},
        {"format": "fignetctl.prompts", "format_version": 1, "objects": [{"name": "a", "points": "abc"}]},
        {"format": "fignetctl.prompts", "format_version": 1, "objects": []},
        {
            "format": "fignetctl.prompts",
            "format_version": 1,
            "objects": [
                {
                    "name": "a",
                    "points": [{"image": "v0.png", "u": 1e400, "v": 2}, {"image": "v1.png", "u": 1, "v": 2}],
                }
            ],
        },
        {
            "format": "fignetctl.prompts",
            "format_version": 1,
            "objects": [{"name": "a", "points": [{"image": "v0.png", "u": float("nan"), "v": 2}]}],
        },
        {
            "format": "fignetctl.prompts",
            "format_version": 1,
            "objects": [
                {
                    "name": "a",
                    "points": [{"image": "v0.png", "u": 1e30, "v": 2}, {"image": "v1.png", "u": -5, "v": 2}],
                }
            ],
        },
        {
            "format": "fignetctl.prompts",
            "format_version": 1,
            "objects": [{"name": "a", "points": [{"image": "nope.png", "u": 1, "v": 2}]}],
        },
    ],
)
def test_prompts_json_of_the_wrong_shape(tmp_path, document):
    import json

    from fignetctl.core.cameras import read_cameras
    from fignetctl.stages.extract_mesh import read_prompts_json

    cameras = read_cameras(_cameras_file(tmp_path / "cameras.npz"))
    path = tmp_path / "prompts.json"
    path.write_text(json.dumps(document))
    _refuses_clearly(lambda p: read_prompts_json(p, cameras), path)
    path.write_text("[" * 100000 + "]" * 100000)
    _refuses_clearly(lambda p: read_prompts_json(p, cameras), path)


def test_trajectory_file_of_the_wrong_shape(tmp_path):
    import shutil

    import h5py

    good = write_trajectories(tmp_path / "good.h5", box_drop_file(frames=4), compression=None)

    def replaced(group, name, value):
        def change(f):
            del f[group][name]
            f[group].create_dataset(name, data=value)

        return change

    def huge_sparse_positions(f):
        del f["trajectories/00000/positions"]
        f["trajectories/00000"].create_dataset(
            "positions", shape=(10**7, 10**6, 3), dtype="f4", chunks=(1, 1000, 3)
        )

    def mesh_is_a_dataset(f):
        del f["meshes/box"]
        f["meshes"].create_dataset("box", data=np.zeros(3))

    changes = [
        replaced("trajectories/00000", "positions", np.array([b"abc"] * 4)),
        replaced("trajectories/00000", "mesh_names", np.arange(2)),
        replaced("trajectories/00000", "mass", np.zeros(2, dtype=[("a", "f4"), ("b", "i4")])),
        replaced("meshes/box", "vertices", np.zeros((3, 3), np.complex64)),
        mesh_is_a_dataset,
        huge_sparse_positions,
        lambda f: f.attrs.__setitem__("dt", "fast"),
        lambda f: f.attrs.__setitem__("gravity", "down"),
    ]
    for index, change in enumerate(changes):
        path = tmp_path / f"changed-{index}.h5"
        shutil.copy(good, path)
        with h5py.File(path, "a") as f:
            change(f)
        _refuses_clearly(read_trajectories, path, FormatError)


# --- Containers that get past the first check ---


def _npz_member_replaced(source, target, member, transform):
    """A copy of the .npz `source` whose `member` (.npy) bytes are transform(bytes)."""
    import zipfile

    with zipfile.ZipFile(source) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members[member] = transform(members[member])
    with zipfile.ZipFile(target, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return target


def _header_unclosed(data: bytes) -> bytes:
    """The .npy header's dict left open: numpy's header parser meets the end of its text."""
    length = int.from_bytes(data[8:10], "little")
    header = data[10 : 10 + length].replace(b"}", b" ").replace(b"(", b"((")
    return data[:10] + header + data[10 + length :]


@pytest.mark.parametrize(
    "transform", [_header_unclosed, lambda data: data[:20], lambda data: data[:10] + b"\xff" * 40]
)
def test_npz_members_with_a_damaged_npy_header_are_refused_in_one_line(tmp_path, transform):
    from fignetctl.core.cameras import read_cameras
    from fignetctl.stages.extract_mesh import read_depth

    cameras = _cameras_file(tmp_path / "cameras.npz")
    damaged = _npz_member_replaced(cameras, tmp_path / "damaged.npz", "K.npy", transform)
    _refuses_clearly(read_cameras, damaged, FormatError)
    np.savez(tmp_path / "depth.npz", depth=np.ones((8, 48, 64)))
    depth = _npz_member_replaced(tmp_path / "depth.npz", tmp_path / "d.npz", "depth.npy", transform)
    from fignetctl.core.cameras import read_cameras as read

    _refuses_clearly(lambda path: read_depth(path, read(cameras)), depth, FormatError)


def test_a_valid_trajectory_file_with_gcol_bytes_and_an_object_reference_is_read(tmp_path):
    """Bytes that look like a global heap's signature inside a dataset or an attribute, and an
    attribute holding an HDF5 object reference: the file reads (the reference is left out)."""
    import h5py

    path = write_trajectories(tmp_path / "t.h5", box_drop_file(frames=6), compression=None)
    with h5py.File(path, "a") as f:
        f.attrs["link"] = f["meshes"].ref
        f.create_dataset("extra", data=np.frombuffer(b"GCOL\x01" + bytes(range(200)), np.uint8))
        f.attrs["blob"] = np.void(b"GCOL\x01\x00\x00\x00" + b"\xff" * 8 + bytes(40))
        f.attrs["note"] = "GCOL\x01\x10 in a note"
    data = read_trajectories(path)
    assert len(data.trajectories) == 1 and "link" not in data.attrs and "blob" not in data.attrs
    assert data.attrs["note"].startswith("GCOL")


def _png_claiming(width: int, height: int) -> bytes:
    """A few hundred bytes of PNG whose header declares width x height pixels."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(bytes(64)))
        + chunk(b"IEND", b"")
    )


def test_an_image_declaring_billions_of_pixels_is_refused_in_one_line(tmp_path):
    import cv2

    from fignetctl.core.media import read_image
    from fignetctl.core.sfm import list_images

    (tmp_path / "images").mkdir()
    bomb = tmp_path / "images" / "bomb.png"
    bomb.write_bytes(_png_claiming(100_000, 100_000))
    for flags in (None, cv2.IMREAD_COLOR, cv2.IMREAD_GRAYSCALE):
        with pytest.raises(FormatError, match="more pixels than OpenCV reads") as caught:
            read_image(bomb, flags)
        assert "\n" not in str(caught.value)
    _refuses_clearly(list_images, tmp_path / "images", FormatError)


# --- Damage inside the numbers themselves: checksums make it an error, not other numbers ---


def test_a_changed_weight_is_refused_by_its_checksum(tmp_path):
    import torch

    simulator = LearnedSimulator(SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1)))
    path = save_checkpoint(tmp_path / "m.pt", simulator)
    payload = torch.load(path, weights_only=True)
    name = next(k for k, v in payload["model"].items() if v.is_floating_point() and v.numel())
    payload["model"][name].view(-1)[0] += 1e-3  # what one flipped bit in the weights does
    torch.save(payload, tmp_path / "changed.pt")
    load_checkpoint(path)  # the untouched file reads
    with pytest.raises(FormatError, match="checksum; the file is damaged"):
        load_checkpoint(tmp_path / "changed.pt")


@pytest.mark.parametrize("compression", [None, "gzip"])
def test_a_flipped_byte_in_a_trajectory_dataset_is_refused(tmp_path, compression):
    import h5py

    path = write_trajectories(tmp_path / "t.h5", box_drop_file(frames=6), compression=compression)
    with h5py.File(path, "r") as f:
        dataset = f["trajectories/00000/positions"]
        assert dataset.fletcher32
        chunk = dataset.id.get_chunk_info(0)
    data = bytearray(path.read_bytes())
    data[chunk.byte_offset + chunk.size // 2] ^= 0x10
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(bytes(data))
    with pytest.raises(FormatError) as caught:
        read_trajectories(damaged)
    assert str(caught.value).startswith(str(damaged)) and "\n" not in str(caught.value)
