"""Training a learned simulator on a trajectory file, with exact resume.

Each step draws `batch_size` examples (a trajectory and a frame t with t−1 and t+1 around
it), jitters the pose of every dynamic object at t (noise.py), builds each graph, and
regresses the normalized accelerations of the dynamic mesh nodes with an MSE loss (with
`pushforward`, that many of them take frame t from the simulator's own prediction instead, or
from a fixed model's with `pushforward_model`; with `unroll` n ≥ 2, each example's answer also
starts a second step that is scored too, and so on for n steps, unroll.py; with
`frame_sampling` 'motion', impact frames are drawn more often and weighted less).
Adam with a learning rate decaying exponentially from `learning_rate_initial` to
`learning_rate_final`.

Throughput: the batches are built in worker processes (`TrainingBatches` behind a torch
DataLoader) while the training process runs the network, and the network runs in bfloat16
mixed precision where the processor does bfloat16 matrix products natively
(`TrainingSettings.precision`); docs/simulator.md has the measured samples per second.

Everything random in batch k comes from generators seeded with (seed, rank, k), so a batch is
the same whichever process builds it and whenever, and a run resumed from a checkpoint reaches
the same weights as one that never stopped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.atomic import process_running
from fignetctl.core.model import distributed
from fignetctl.core.model.checkpoint import load_checkpoint, save_checkpoint
from fignetctl.core.model.graph import batch_graphs
from fignetctl.core.model.network import mlp_widened, silence
from fignetctl.core.model.noise import apply_rigid_pose_noise_to_poses, sample_rigid_pose_noise
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, SceneStore, frame_counts, property_inputs
from fignetctl.core.model.scene_graph import (
    INERTIA_FEATURE_SIZE,
    NODE_FEATURE_SIZE,
    NODE_NODE,
    build_scene_graph,
    rigid_point_velocities,
)
from fignetctl.core.model.simulator import (
    LearnedSimulator,
    SimulatorConfig,
    acceleration_targets,
    free_motion_of,
)
from fignetctl.core.model.trained_ranges import property_ranges, ranges_to_json
from fignetctl.core.model.unroll import batch_later_steps, check_unrollable, later_step, later_step_loss
from fignetctl.core.provenance import INPUTS_KEY, file_sha256, stamp
from fignetctl.core.trajectory import read_trajectories
from fignetctl.core.transforms import quat_conjugate, quat_multiply, quat_to_rotation_vector
from fignetctl.errors import FignetError


@dataclasses.dataclass(frozen=True)
class TrainingSettings:
    """How long and how a simulator is trained."""

    steps: int = 20000
    """Optimiser steps."""
    batch_size: int = 4
    """Scenes (graphs) per step."""
    learning_rate_initial: float = 1e-3
    learning_rate_final: float = 1e-4
    """Exponential decay from the first to the second over `steps` (the paper: 1e-3 -> 1e-4)."""
    noise_translation_std: float = 0.003
    """Std (m) of the per-object translation jitter on frame t."""
    noise_rotation_std: float = 0.003
    """Std (rad) of the per-object rotation jitter on frame t."""
    target_keeps_noise: bool = True
    """True: the target next vertices carry the jitter of frame t too (as in Sanchez-Gonzalez
    et al. 2020), so the network learns to undo velocity noise only: a resting object with a
    small velocity v is told a = −v and stops. False (model files before this field): the
    target undoes the position noise as well, a = −2v, which a rollout turns into a
    period-2 oscillation of resting objects (±v every frame, for ever)."""
    position_noise_undone: float = 0.0
    """With `target_keeps_noise`, the fraction α of frame t's pose noise that the target position
    still undoes (0: none). It teaches the network to move an object α of the way back onto the
    recording in one step, which it can tell only where contact shows where the object belongs
    (pushed into the floor, or lifted off it). A velocity state's velocity target is the
    recording's whatever α, so nothing oscillates; for a positions state α = 1 is the target of
    `target_keeps_noise` False, whose a = −2v does."""
    loss: str = "mse"
    """'mse' (the paper) or 'huber' on the normalized accelerations."""
    unroll: int = 1
    """Steps the loss follows the simulator through: 1 (the paper's one-step loss), or n ≥ 2:
    each example's answer for t+1 is also the state of a second step, scored against t+2, and
    so on to t+n, each step's gradient reaching every earlier answer (unroll.py); the loss is
    the steps' mean. An example near the end of its recording takes the steps it has."""
    velocity_weight: float = 1.0
    """A velocity state's loss weight of the velocity columns a_u against the position columns
    a_x (1: equal). An error in u_{t+1} moves every later frame of a rollout, one in x_{t+1}
    only that one, so after k steps the first weighs about k − 1 times the second; the
    weights are scaled so the six columns' average stays 1."""
    huber_delta: float = 0.5
    """Where the Huber loss turns from quadratic to linear, in target standard deviations."""
    pushforward: int = 0
    """Examples of each batch (of `batch_size`) whose frame t is the simulator's own prediction
    from the true frame t−1, without a gradient through that prediction, instead of a noisy copy
    of the truth (the pushforward trick of Brandstetter et al. 2022: the network meets the
    errors its own rollouts make); built in the training process (by the workers with a
    `pushforward_model`), ordinary examples until the normalizers freeze."""
    pushforward_model: str = ""
    """A model file: the `pushforward` examples start from its predictions, a fixed model's,
    instead of the trained one's, and are built with the others, by the workers, so they
    scale with them ("" : from the trained model, in the training process)."""
    frame_sampling: str = "uniform"
    """Which frames the examples are: 'uniform' (a trajectory, then a frame t, each uniformly),
    or 'motion': half of the draws so and half in proportion to how much the frame's motion
    changes (`frame_motion`), each example's loss weighted by uniform/actual probability, so the
    expected loss stays the uniform one while the rare impact frames that carry most of it are
    drawn more often."""
    calm_weight: float = 0.0
    """Extra loss weight of the dynamic vertices that the recording moves in free fall or keeps
    at rest from frame t to t + 1 (`calm_vertices`): their loss weighs 1 + calm_weight. Their
    targets are small and simple, so under a loss that impacts dominate they are fitted
    loosely, and a rollout adds those small errors up frame after frame."""
    rest_weight: float = 0.0
    """Extra loss weight of the dynamic vertices whose object the recording keeps at rest (or
    sliding or rolling steadily) from frame t to t + 1 (`object_regimes`), on top of
    `calm_weight`: with the velocity noise on its input, such an example is a resting object
    given a small velocity and told to stop, which an MSE dominated by impacts hardly sees."""
    normalizer_accumulation_steps: int = 500
    """Normalizer statistics are gathered over the first this many steps, then frozen."""
    checkpoint_every: int = 500
    """Steps between checkpoints."""
    added_blocks_from: int = 0
    """Processor blocks from this index on were added to a trained model of that many blocks
    (`init_from`) and start as identity (`network.silence`); 0: none were added."""
    added_blocks_learning_rate_scale: float = 1.0
    """The added blocks' learning rate as a multiple of the others': their LayerNorm scales
    start at zero and Adam moves a parameter by about the learning rate a step, so at a
    fine-tuning rate they stay near zero for thousands of steps."""
    seed: int = 0
    precision: str = "fp32"
    """'fp32', or 'bf16': the network's forward and backward pass under bfloat16 autocast
    (weights, optimiser and loss stay float32); 2.1x the samples per second on a CPU with
    native bfloat16 (docs/simulator.md)."""

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


def resolve_precision(precision: str, device: str) -> str:
    """'auto' -> 'bf16' on a CUDA device with bfloat16 or a CPU with native bfloat16
    instructions (avx512_bf16 or amx_bf16; emulated bfloat16 is slower than float32), else 'fp32'."""
    if precision != "auto":
        return precision
    if str(device).startswith("cuda"):
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    try:
        flags = Path("/proc/cpuinfo").read_text().split()
    except OSError:
        return "fp32"
    return "bf16" if {"avx512_bf16", "amx_bf16"} & set(flags) else "fp32"


@contextlib.contextmanager
def torch_threads(threads):
    """Run the block with `threads` torch intra-op threads (None: unchanged), then restore."""
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def network_threads(workers: int, device: str):
    """A `torch_threads` block with as many threads as the cores the `workers` leave free (at
    least one), on the CPU, so that the graph builders and the network's threads never share a
    core: a thread that waits for its core stalls every parallel region of the network. An
    OMP_NUM_THREADS in the environment (torchrun sets one) is kept."""
    if str(device).startswith("cuda") or "OMP_NUM_THREADS" in os.environ:
        return torch_threads(None)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return torch_threads(max(1, cores - workers))


def learning_rate_factor(step: int, config: TrainingSettings) -> float:
    """Multiplier of the initial rate at `step`: 1 at 0, final/initial at `steps`."""
    ratio = config.learning_rate_final / config.learning_rate_initial
    return ratio ** (min(step, config.steps) / max(config.steps, 1))


def parameter_groups(simulator, config: TrainingSettings) -> list[dict]:
    """Adam's parameter groups: one, or with a scaled learning rate for the processor blocks
    added from `config.added_blocks_from` on, a second for those (its "scale")."""
    if config.added_blocks_from == 0 or config.added_blocks_learning_rate_scale == 1.0:
        return [{"params": list(simulator.parameters())}]
    added = {
        id(p) for block in simulator.network.processor[config.added_blocks_from :] for p in block.parameters()
    }
    return [
        {"params": [p for p in simulator.parameters() if id(p) not in added]},
        {
            "params": [p for p in simulator.parameters() if id(p) in added],
            "scale": config.added_blocks_learning_rate_scale,
        },
    ]


def jitter_frame_t(positions, quaternions, static, generator, config: TrainingSettings):
    """Per-object rigid noise (noise.py) on frame t (index 1) of (3, O, 3) / (3, O, 4) poses; copies."""
    noise = sample_rigid_pose_noise(
        torch.from_numpy(~static), config.noise_translation_std, config.noise_rotation_std, generator
    )
    positions, quaternions = np.array(positions, np.float64), np.array(quaternions, np.float64)
    positions[1], quaternions[1] = apply_rigid_pose_noise_to_poses(positions[1], quaternions[1], noise)
    return positions, quaternions


def jittered_step_velocities(scene, frame, generator, config: TrainingSettings):
    """Linear and angular velocities (O, 3) at `frame` in metres and radians per step, with
    per-object noise of the pose noise's standard deviations (none on static objects)."""
    noise = sample_rigid_pose_noise(
        torch.from_numpy(~scene.geometry.static),
        config.noise_translation_std,
        config.noise_rotation_std,
        generator,
    )
    linear = scene.velocities[frame] * scene.dt + noise.translations.double().numpy()
    angular = scene.angular_velocities[frame] * scene.dt + noise.rotation_vectors.double().numpy()
    return linear, angular


def training_example(simulator_config, scene, frame, generator, config: TrainingSettings):
    """One noisy example: the raw graph and the raw targets of its dynamic vertices, (Vd, 3)
    accelerations, or (Vd, 6) position and velocity corrections for a velocity state
    (simulator.py's module docstring)."""
    positions, quaternions = jitter_frame_t(
        scene.positions[frame - 1 : frame + 2],
        scene.quaternions[frame - 1 : frame + 2],
        scene.geometry.static,
        generator,
        config,
    )
    velocities = (
        jittered_step_velocities(scene, frame, generator, config)
        if simulator_config.uses_velocities
        else None
    )
    return example_from_state(simulator_config, scene, frame, positions, quaternions, velocities, config)


def pushforward_example(simulator, scene, frame, config: TrainingSettings, example_config=None):
    """The example at `frame` (2 ≤ frame ≤ T − 2) whose frame t is what `simulator` predicts from
    the true frames before it (and the true velocities at t − 1 for a velocity state), as a graph
    of `example_config` (the trained simulator's; default: `simulator`'s)."""
    window = slice(frame - 2, frame + 1)
    velocities = None
    if simulator.config.uses_velocities:
        velocities = (scene.velocities[frame - 1], scene.angular_velocities[frame - 1])
    predicted = simulator.predict(
        scene.geometry, scene.positions[window], scene.quaternions[window], velocities=velocities
    )
    positions = np.array(scene.positions[frame - 1 : frame + 2], np.float64)
    quaternions = np.array(scene.quaternions[frame - 1 : frame + 2], np.float64)
    positions[1], quaternions[1] = predicted[0], predicted[1]
    step_velocities = None
    if simulator.config.uses_velocities:
        step_velocities = (predicted[2] * scene.dt, predicted[3] * scene.dt)
    return example_from_state(
        example_config or simulator.config, scene, frame, positions, quaternions, step_velocities, config
    )


def example_from_state(simulator_config, scene, frame, positions, quaternions, velocities, config):
    """The raw graph of frames t − 1, t, t + 1 = `frame` + (−1, 0, 1) as given ((3, O, 3),
    (3, O, 4); frame t may differ from the scene's, by noise or a prediction; frame t + 1 is the
    scene's) with `velocities` (per step, or None), and the raw targets that reach the scene's
    frame t + 1 (shifted by frame t's difference from the scene's when the target keeps it, less
    the `position_noise_undone` fraction of it)."""
    geometry = scene.geometry
    scene_graph = build_scene_graph(geometry, positions, quaternions, simulator_config.graph, velocities)
    previous, now, after = scene_graph.dynamic_vertex_positions
    if config.target_keeps_noise:
        after = after + kept_noise(scene, frame, now, config)
    next_velocities = None
    if velocities is not None:
        next_velocities = rigid_point_velocities(
            geometry.world_vertices(
                scene.positions[frame + 1], scene.quaternions[frame + 1], geometry.dynamic_vertices
            ),
            geometry.vertex_object[geometry.dynamic_vertices],
            scene.positions[frame + 1],
            scene.velocities[frame + 1] * scene.dt,
            scene.angular_velocities[frame + 1] * scene.dt,
        )
    free_motion = free_motion_of(simulator_config, geometry, now, positions[1], velocities)
    targets = acceleration_targets(after, previous, now, next_velocities, free_motion)
    return scene_graph, torch.from_numpy(targets.astype(np.float32))


CALM_TOLERANCE = 0.1
"""How close (a fraction of |g| dt², per frame) an object's change of motion over a step must
come to free fall's or to none for `calm_vertices`."""


def motion_change(scene, frame, velocity_state=True):
    """How the recording changes each object's motion from frame t = `frame` to t + 1: (O, 3)
    the change of its centre's velocity and (O,) that of its angular velocity times its
    farthest vertex's distance from the centre, both in metres per frame per frame. From the
    recorded velocities at t and t + 1 for a `velocity_state` model (what its target spans),
    else from the finite differences of the poses at t − 1, t, t + 1 (a two-frame model's)."""
    geometry, dt = scene.geometry, scene.dt
    if velocity_state:
        linear = (scene.velocities[frame + 1] - scene.velocities[frame]) * dt
        angular = (scene.angular_velocities[frame + 1] - scene.angular_velocities[frame]) * dt
    else:
        p, q = scene.positions, scene.quaternions
        linear = p[frame + 1] - 2 * p[frame] + p[frame - 1]
        turns = [quat_multiply(q[k + 1], quat_conjugate(q[k])) for k in (frame, frame - 1)]
        angular = quat_to_rotation_vector(turns[0]) - quat_to_rotation_vector(turns[1])
    return np.asarray(linear, np.float64), np.linalg.norm(angular, axis=1) * geometry.object_reach


REGIMES = ("free fall", "at rest or steady", "impact", "other contact")
IMPACT = 5.0
"""An object's step is an impact when its motion changes beyond gravity's by more than this many
|g| dt² per frame (at its centre, or from its spin at its farthest vertex)."""


def object_regimes(scene, frame, gravity, velocity_state=True) -> np.ndarray:
    """(O,) index into REGIMES of what the recording does with each object from frame t =
    `frame` to t + 1 (`motion_change`): free fall (its centre's velocity changes by gravity's
    g dt) or at rest (or sliding or rolling steadily: it does not change), each within
    CALM_TOLERANCE |g| dt² per frame and without a change of spin; an impact past IMPACT;
    other contact otherwise. `gravity` in m/s²."""
    linear, angular = motion_change(scene, frame, velocity_state)
    fall = np.asarray(gravity, np.float64) * scene.dt**2
    unit = np.linalg.norm(fall)
    beyond = np.linalg.norm(linear - fall, axis=1)
    spinning = angular >= CALM_TOLERANCE * unit
    regime = np.full(len(linear), REGIMES.index("other contact"))
    regime[(beyond < CALM_TOLERANCE * unit) & ~spinning] = REGIMES.index("free fall")
    regime[(np.linalg.norm(linear, axis=1) < CALM_TOLERANCE * unit) & ~spinning] = REGIMES.index(
        "at rest or steady"
    )
    regime[np.maximum(beyond, angular) > IMPACT * unit] = REGIMES.index("impact")
    return regime


def vertex_regimes(scene, frame, gravity, velocity_state=True) -> np.ndarray:
    """(Vd,) `object_regimes` of the object of each of the scene's dynamic vertices."""
    geometry = scene.geometry
    regimes = object_regimes(scene, frame, gravity, velocity_state)
    return regimes[geometry.vertex_object[geometry.dynamic_vertices]]


def calm_vertices(scene, frame, gravity, velocity_state=True) -> np.ndarray:
    """(Vd,) bool of the scene's dynamic vertices: whether the recording moves their object from
    frame t = `frame` to t + 1 in free fall or keeps it at rest (`object_regimes`)."""
    return vertex_regimes(scene, frame, gravity, velocity_state) < REGIMES.index("impact")


FRAME_SAMPLINGS = ("uniform", "motion")
MOTION_SHARE = 0.5
"""The share of 'motion' draws made in proportion to the frames' motion change (the rest are
uniform, which keeps every loss weight at most 1 / (1 - MOTION_SHARE))."""


MOTION_RESOLUTION = 1e-5
"""Metres per frame² of `frame_motion` that are the float32 poses' rounding, not motion."""


def frame_motion(scene, gravity) -> np.ndarray:
    """(T − 2,) for frames t = 1 … T − 2: the RMS over the dynamic vertices of the change of
    their motion from t − 1 → t to t → t + 1, beyond what gravity (m/s², (3,)) gives, less
    MOTION_RESOLUTION: 0 in free flight, g dt² at rest, and large in impacts."""
    geometry = scene.geometry
    vertices = np.stack(
        [
            geometry.world_vertices(p, q, geometry.dynamic_vertices)
            for p, q in zip(scene.positions, scene.quaternions)
        ]
    )
    change = vertices[2:] - 2 * vertices[1:-1] + vertices[:-2] - np.asarray(gravity) * scene.dt**2
    rms = np.sqrt(np.mean(np.sum(change**2, axis=-1), axis=-1))
    return np.maximum(rms - MOTION_RESOLUTION, 0.0)


class FrameSampler:
    """Draws the (scene, frame t, loss weight) of each training example from a generator, as
    `frame_sampling` says (TrainingSettings); 'uniform' makes the same draws, weight 1, as
    training always did."""

    def __init__(self, scenes, mode: str = "uniform", gravity=None):
        if mode not in FRAME_SAMPLINGS:
            raise FignetError(f"frame_sampling = {mode!r}: choose one of {', '.join(FRAME_SAMPLINGS)}")
        self.mode, self.frames = mode, [n - 2 for n in frame_counts(scenes)]
        if mode == "uniform":
            return
        if gravity is None:
            raise FignetError("frame_sampling 'motion' needs the data's gravity (the simulator config's)")
        uniform = np.concatenate([np.full(n, 1.0 / (len(scenes) * n)) for n in self.frames])
        motion = np.concatenate([frame_motion(s, gravity) for s in scenes])
        total = motion.sum()
        probability = uniform if total == 0 else (1 - MOTION_SHARE) * uniform + MOTION_SHARE * motion / total
        self.cumulative = np.cumsum(probability) / probability.sum()
        self.weights = uniform / probability
        self.starts = np.cumsum([0, *self.frames])

    def draw(self, rng) -> tuple[int, int, float]:
        if self.mode == "uniform":
            scene = int(rng.integers(len(self.frames)))
            return scene, int(rng.integers(1, self.frames[scene] + 1)), 1.0  # t−1 and t+1 inside
        index = min(int(np.searchsorted(self.cumulative, rng.random(), side="right")), len(self.weights) - 1)
        scene = int(np.searchsorted(self.starts, index, side="right")) - 1
        return scene, 1 + index - int(self.starts[scene]), float(self.weights[index])


def pushforward_examples(simulator, scenes, example_config, config: TrainingSettings, rank, step) -> dict:
    """The `pushforward` examples of batch `step` (from (seed, rank, step) alone, as the others)
    on frames `simulator` predicted, as graphs of `example_config`; ordinary noisy ones while the
    normalizers are still gathering or where a trajectory is under four frames long."""
    rng = np.random.default_rng([config.seed, rank, step, 1])
    noise_generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
    ordinary = step < config.normalizer_accumulation_steps
    examples, weights = [], []
    for _ in range(config.pushforward):
        scene = scenes[rng.integers(len(scenes))]
        frames = scene.positions.shape[0]
        frame = int(rng.integers(2, frames - 1)) if frames >= 4 else 1
        if ordinary or frames < 4:
            examples.append(training_example(example_config, scene, frame, noise_generator, config))
        else:
            examples.append(pushforward_example(simulator, scene, frame, config, example_config))
        weights.append(row_weights(scene, frame, example_config, config))
    return batch_of(examples, weights if weighs_rows(config) else None)


class TrainingBatches(torch.utils.data.Dataset):
    """Batch k of a run, built from (seed, rank, k) alone: picklable, so DataLoader workers
    build batches while the training process runs the network. With a `pushforward_simulator`
    (the fixed model of `pushforward_model`) the batches hold the pushforward examples too."""

    def __init__(
        self, scenes, simulator_config, config: TrainingSettings, rank: int = 0, pushforward_simulator=None
    ):
        self.scenes, self.simulator_config, self.config, self.rank = scenes, simulator_config, config, rank
        self.sampler = FrameSampler(scenes, config.frame_sampling, simulator_config.gravity)
        self.pushforward_simulator = pushforward_simulator

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> dict:
        """`batch_of` the step's examples, the `pushforward` ones only with a fixed model."""
        rng = np.random.default_rng([self.config.seed, self.rank, step])
        noise_generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
        examples, weights = [], []
        draws = []
        for _ in range(self.config.batch_size - self.config.pushforward):  # Trainer adds the others
            scene, frame, weight = self.sampler.draw(rng)
            draws.append((scene, frame, weight))
            examples.append(
                training_example(
                    self.simulator_config, self.scenes[scene], frame, noise_generator, self.config
                )
            )
            weights.append(
                weight * row_weights(self.scenes[scene], frame, self.simulator_config, self.config)
            )
        weighted = self.config.frame_sampling != "uniform" or weighs_rows(self.config)
        later = None
        if self.config.unroll > 1:
            later = [
                later_steps_of(
                    self.simulator_config, self.scenes[scene], frame, example[0], weight, self.config
                )
                for (scene, frame, weight), example in zip(draws, examples, strict=True)
            ]
        batch = batch_of(examples, weights if weighted else None, later)
        if self.pushforward_simulator is not None:  # only with pushforward examples to start
            with torch_threads(1):  # as in a worker: the same sums, so the same batch in any process
                own = pushforward_examples(
                    self.pushforward_simulator,
                    self.scenes,
                    self.simulator_config,
                    self.config,
                    self.rank,
                    step,
                )
            batch = joined(batch, own)
        return batch


def fixed_pushforward_model(config: TrainingSettings, simulator_config):
    """The fixed model of `config.pushforward_model` on the CPU (None without one), or a clear
    error when it cannot start from the trained model's state."""
    if not config.pushforward_model:
        return None
    if not config.pushforward:
        raise FignetError(
            f"pushforward_model = {config.pushforward_model!r} with pushforward = 0: it starts the "
            "pushforward examples, so give some"
        )
    model = load_checkpoint(config.pushforward_model).eval()
    if model.config.uses_velocities != simulator_config.uses_velocities:
        raise FignetError(
            f"{config.pushforward_model}: its state is {model.config.state!r}, the trained model's "
            f"{simulator_config.state!r}; give a pushforward model of the trained model's state"
        )
    return model


def weighs_rows(config: TrainingSettings) -> bool:
    """Whether `row_weights` gives some vertices more than 1."""
    return bool(config.calm_weight or config.rest_weight)


def row_weights(scene, frame, simulator_config, config: TrainingSettings):
    """The loss weights of the dynamic vertices of the example at `frame`: 1, or (Vd,) with
    1 + calm_weight on `calm_vertices` and rest_weight more on those at rest."""
    if not weighs_rows(config):
        return 1.0
    regimes = vertex_regimes(scene, frame, simulator_config.gravity, simulator_config.uses_velocities)
    return (
        1.0
        + config.calm_weight * (regimes < REGIMES.index("impact"))
        + config.rest_weight * (regimes == REGIMES.index("at rest or steady"))
    )


def batch_of(examples, weights=None, later=None) -> dict:
    """{"graph": the batched raw graph, "rows": its dynamic vertex nodes, "targets": their raw
    targets, with `weights` (per example, a number or one per dynamic vertex) "weights":
    each row's loss weight, and with `later` (per example, the list of its unroll.LaterSteps)
    "later": the batch's LaterSteps, one per step after the first that some example has}."""
    batch = {
        "graph": batch_graphs([e[0].graph for e in examples]),
        "rows": dynamic_rows([e[0] for e in examples]),
        "targets": torch.cat([e[1] for e in examples]),
    }
    if weights is not None:
        batch["weights"] = torch.cat(
            [
                torch.as_tensor(np.ones(len(e[1])) * w, dtype=torch.float32)
                for e, w in zip(examples, weights, strict=True)
            ]
        )
    if later is not None:
        batch["later"] = []
        chains, sizes = list(later), [len(e[1]) for e in examples]
        for k in range(max(map(len, chains), default=0)):
            starts = np.cumsum([0] + sizes[:-1])
            kept = [(chain, start) for chain, start in zip(chains, starts, strict=True) if len(chain) > k]
            batch["later"].append(batch_later_steps([c[k] for c, _ in kept], [s for _, s in kept]))
            chains, sizes = [c for c, _ in kept], [len(c[k].first) for c, _ in kept]
    return batch


def kept_noise(scene, frame, now, config: TrainingSettings):
    """The part of frame t's difference from the scene's that the target keeps: the dynamic
    vertices `now` (Vd, 3) less the recording's at `frame`, less the `position_noise_undone`
    fraction of it."""
    geometry = scene.geometry
    recorded_now = geometry.world_vertices(
        scene.positions[frame], scene.quaternions[frame], geometry.dynamic_vertices
    )
    return (1.0 - config.position_noise_undone) * (now - recorded_now)


def later_steps_of(simulator_config, scene, frame, first_graph, weight, config: TrainingSettings):
    """The unroll.LaterSteps of the example at `frame` (its SceneGraph `first_graph`, its frame
    sampling weight `weight`): the recording's steps from t+1 to t+`unroll`−1, as many of them
    as the recording holds the frame after."""
    geometry = scene.geometry
    start = np.zeros((len(geometry.dynamic_vertices), 3))
    if config.target_keeps_noise:
        start = kept_noise(scene, frame, first_graph.dynamic_vertex_positions[1], config)
    steps = []
    for now in range(frame + 1, min(frame + config.unroll, scene.positions.shape[0] - 1)):
        window = slice(now - 1, now + 2)
        velocities = (scene.velocities[now] * scene.dt, scene.angular_velocities[now] * scene.dt)
        scene_graph, targets = example_from_state(
            simulator_config,
            scene,
            now,
            scene.positions[window],
            scene.quaternions[window],
            velocities,
            config,
        )
        steps.append(
            later_step(
                scene_graph,
                targets.numpy(),
                geometry,
                scene.positions[now],
                start,
                weight * row_weights(scene, now, simulator_config, config),
                simulator_config.graph.max_vertex_offset,
            )
        )
    return steps


def joined(first: dict, second: dict) -> dict:
    """Two `batch_of` batches as one (rows without a weight weigh 1)."""
    batch = {
        "graph": batch_graphs([first["graph"], second["graph"]]),
        "rows": torch.cat([first["rows"], second["rows"] + first["graph"].num_nodes]),
        "targets": torch.cat([first["targets"], second["targets"]]),
    }
    if "weights" in first or "weights" in second:
        batch["weights"] = torch.cat(
            [b.get("weights", torch.ones(len(b["targets"]))) for b in (first, second)]
        )
    return batch


PREFETCH_FACTOR = 4
"""Batches each worker builds ahead of the trainer."""


def batch_stream(batches: TrainingBatches, start: int, stop: int, workers: int):
    """Batches start .. stop−1, built by `workers` processes (0: in this one).

    The workers start from a fresh interpreter (forkserver, or spawn where there is none) and
    are sent the scenes: forking the training process itself can copy a lock another of its
    threads holds, and the worker then waits for ever (seen under pytest)."""
    if workers == 0:
        return (batches[k] for k in range(start, stop))
    import multiprocessing

    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    return iter(
        torch.utils.data.DataLoader(
            batches,
            batch_size=None,
            sampler=range(start, stop),
            num_workers=workers,
            prefetch_factor=PREFETCH_FACTOR,
            multiprocessing_context=multiprocessing.get_context(method),
            worker_init_fn=functools.partial(end_with_process, os.getpid()),
        )
    )


def end_with_process(pid: int, worker_id: int = 0) -> None:
    """DataLoader `worker_init_fn`: end this worker as soon as process `pid` (the trainer) has
    ended. torch's own watchdog watches a worker's parent, which under forkserver is the fork
    server, so without this a trainer killed by a signal or the out-of-memory killer would leave
    its workers behind, each holding the training file's arrays and its own scenes."""
    import select
    import threading

    def wait_for_exit():
        try:
            handle = os.pidfd_open(pid)  # readable once the process has ended
        except (AttributeError, OSError):  # no pidfd here (or it has ended): look every second
            while process_running(pid):
                time.sleep(1.0)
        else:
            select.select([handle], [], [])
        os._exit(1)

    threading.Thread(target=wait_for_exit, name="end-with-trainer", daemon=True).start()


class Trainer:
    """Holds the simulator and optimiser; `run` trains to `config.steps`.

    workers : processes that build batches (0: the training process builds them)
    """

    def __init__(self, scenes, simulator, config: TrainingSettings, device="cpu", data_hash="", workers=0):
        if not 0 <= config.pushforward < config.batch_size:
            raise FignetError(
                f"pushforward = {config.pushforward}: give 0 to batch_size - 1 ({config.batch_size - 1}); "
                "the others are ordinary examples"
            )
        self.rank, device = distributed.join_process_group(device)
        properties, sides = property_inputs(scenes)
        simulator.trained_properties = property_ranges(properties, np.concatenate(sides) if sides else None)
        self.scenes, self.simulator, self.config = scenes, simulator.to(device), config
        self.model = distributed.data_parallel(self.simulator, device)
        self.device, self.data_hash, self.workers = device, data_hash, workers
        self.optimizer = torch.optim.Adam(
            parameter_groups(simulator, config), lr=config.learning_rate_initial
        )
        self.batches = TrainingBatches(
            scenes, simulator.config, config, self.rank, fixed_pushforward_model(config, simulator.config)
        )
        self.step = 0
        self.history = []
        self.heap = HeapTrimmer()

    def train_step(self, batch=None) -> float:
        """One optimiser step on `batch` (default: this step's batch, built here)."""
        batch = self.batches[self.step] if batch is None else batch
        accumulate = self.step < self.config.normalizer_accumulation_steps
        if self.config.pushforward and not self.config.pushforward_model:
            batch = joined(
                batch,
                pushforward_examples(
                    self.simulator, self.scenes, self.simulator.config, self.config, self.rank, self.step
                ),
            )
        graph = batch["graph"].to(self.device)
        normalized_targets = self.simulator.normalized_targets(batch["targets"].to(self.device), accumulate)
        autocast = functools.partial(
            torch.autocast,
            torch.device(self.device).type,
            dtype=torch.bfloat16,
            enabled=self.config.precision == "bf16",
        )
        with autocast():
            predictions = self.model(graph, accumulate)[batch["rows"].to(self.device)]
        weights = batch.get("weights")
        weights = None if weights is None else weights.to(self.device)
        loss = regression_loss(predictions.float(), normalized_targets, self.config, weights)
        losses, predictions, targets = [loss], predictions.float(), batch["targets"].to(self.device)
        for step in batch.get("later", []):
            later, predictions, targets = later_step_loss(
                self.simulator,
                predictions,
                targets,
                step.to(self.device),
                functools.partial(regression_loss, config=self.config),
                autocast,
            )
            losses.append(later)
        loss = torch.stack(losses).mean()
        self._apply(loss)
        return float(loss.detach())

    def _apply(self, loss):
        rate = self.config.learning_rate_initial * learning_rate_factor(self.step, self.config)
        for group in self.optimizer.param_groups:
            group["lr"] = rate * group.get("scale", 1.0)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        gradients = [p.grad for p in self.simulator.parameters() if p.grad is not None]
        if not torch.stack([g.isfinite().all() for g in gradients]).all():  # the same on every rank
            raise FignetError(
                f"the training loss or its gradient is not finite at step {self.step + 1}; the weights of "
                "the last checkpoint are kept; train again with a lower learning rate"
            )
        self.optimizer.step()
        self.step += 1

    def run(
        self, checkpoint_path=None, on_step=None, until_step=None, on_checkpoint=None, time_limit=None
    ) -> bool:
        """Train until config.steps (or `until_step`), checkpointing every config.checkpoint_every
        steps (and calling `on_checkpoint()` after each checkpoint). With `time_limit` (seconds
        of this call), stop at the first step that ends past it, checkpointed, every rank at the
        same step. Returns whether it stopped there before its last step."""
        now = time.perf_counter()
        started = now - (self.history[-1]["seconds"] if self.history else 0.0)
        deadline = None if time_limit is None else now + time_limit
        last_step = self.config.steps if until_step is None else min(until_step, self.config.steps)
        for batch in batch_stream(self.batches, self.step, last_step, self.workers):
            loss = self.train_step(batch)
            self.heap.step()
            self.history.append({"step": self.step, "loss": loss, "seconds": time.perf_counter() - started})
            if on_step is not None:
                on_step(self.step, loss)
            out_of_time = (
                deadline is not None
                and self.step < last_step
                and any(distributed.gather_from_all(time.perf_counter() >= deadline))
            )
            due = self.step % self.config.checkpoint_every == 0 or self.step == last_step
            if checkpoint_path and (due or out_of_time):
                self.save(checkpoint_path)
                if on_checkpoint is not None:
                    on_checkpoint()
            if out_of_time:
                return True
        return False

    def state(self) -> dict:
        """Everything a resume needs (the batches follow from the step)."""
        return {
            "step": self.step,
            "optimizer": self.optimizer.state_dict(),
            "world_size": distributed.world_size(),
            "history": json.dumps(self.history),
            "training_config": self.config.to_json(),
            "data_hash": self.data_hash,
        }

    def load_state(self, state: dict) -> None:
        processes = int(state["world_size"]) if "world_size" in state else len(json.loads(state["rng"]))
        if processes != distributed.world_size():
            raise FignetError(
                f"the checkpoint was written by {processes} process(es); resume it with as many"
            )
        self.step = int(state["step"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.history = json.loads(state["history"])

    def save(self, path) -> None:
        """Rank 0 writes the checkpoint atomically; the others wait for it."""
        state = self.state()
        if self.rank == 0:
            save_checkpoint(
                path,
                self.simulator,
                training_state=state,
                extra={"trained_properties": ranges_to_json(self.simulator.trained_properties)},
                provenance={
                    **stamp(),
                    INPUTS_KEY: {"training_data": self.data_hash} if self.data_hash else {},
                },
            )
        distributed.barrier()


HEAP_GROWTH = 2.0
"""A trainer's heap is trimmed once its resident memory reaches this many times what it held
after its first step (HeapTrimmer)."""

M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4
"""glibc's `mallopt` parameters (malloc.h)."""


@functools.cache
def _glibc(name):
    """The glibc function `name` (`malloc_trim`, `mallopt`), or None where the C library is not
    glibc."""
    import ctypes
    import ctypes.util

    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None


def _malloc_trim():
    return _glibc("malloc_trim")


def keep_heap_pages() -> bool:
    """Make glibc serve this process's blocks from its heap and keep the pages they free.

    By default glibc maps every block over its mmap threshold (at most 32 MB) on its own pages
    and unmaps it when freed, and hands the heap's free top back to the system; a step of 64
    scenes allocates and frees many tensors of tens of MB, and every page of each is faulted in
    afresh: a trainer took about 90,000 page faults a second and spent 40 % of its time in the
    kernel. With no mapped blocks and no automatic trim, a step reuses the pages the last step
    touched; HeapTrimmer bounds what that keeps (docs/simulator.md, "Memory"). For training
    processes, called by `fignetctl train`. Returns whether glibc took both settings."""
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    return bool(mallopt(M_MMAP_MAX, 0)) & bool(mallopt(M_TRIM_THRESHOLD, 2**31 - 1))


def resident_bytes() -> int | None:
    """This process's resident memory (Linux), None where /proc does not say."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def return_freed_memory() -> None:
    """Hand the heap's free pages back to the system (glibc; elsewhere nothing)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


class HeapTrimmer:
    """Keeps a trainer's resident memory within HEAP_GROWTH times what it held after its first
    step. Every step's graphs differ in size, and glibc keeps the blocks they freed for reuse
    that other sizes do not always find: with glibc's defaults a trainer of 64 scenes grew by
    about 0.5 GB a minute until the kernel killed it. A trimmed page that a later step touches
    comes back as a page fault, so `step()` trims only past the limit, not to what the trainer
    holds between steps (docs/simulator.md, "Memory")."""

    def __init__(self, growth: float = HEAP_GROWTH):
        self.growth, self.limit = growth, 0

    def step(self) -> bool:
        """After a training step: trim if memory grew past the limit (set at the first step).
        Returns whether it did."""
        resident = resident_bytes()
        if resident is None or _malloc_trim() is None:
            return False
        if not self.limit:
            self.limit = self.growth * resident
            return False
        if resident <= self.limit:
            return False
        return_freed_memory()
        return True


def regression_loss(predictions, targets, config: TrainingSettings, weights=None) -> torch.Tensor:
    """Mean loss over nodes and components of the normalized accelerations, each node's
    weighted by `weights` (N,) when given, and a velocity state's columns by `column_weights`."""
    if config.loss == "huber":
        loss = torch.nn.functional.huber_loss(
            predictions, targets, delta=config.huber_delta, reduction="none"
        )
    elif config.loss == "mse":
        loss = (predictions - targets) ** 2
    else:
        raise FignetError(f"unknown loss {config.loss!r}: choose 'mse' or 'huber'")
    if weights is not None:
        loss = loss * weights[:, None]
    if config.velocity_weight != 1.0:
        loss = loss * column_weights(config.velocity_weight, loss.shape[1]).to(loss)
    return torch.mean(loss)


def column_weights(velocity_weight: float, columns: int) -> torch.Tensor:
    """(columns,) loss weights of [a_x, a_u]: 1 and `velocity_weight`, scaled to average 1."""
    if columns != 6:
        raise FignetError("a velocity weight applies to a velocity state's six output columns")
    weights = torch.tensor([1.0] * 3 + [velocity_weight] * 3)
    return weights / weights.mean()


def dynamic_rows(scene_graphs) -> torch.Tensor:
    """Indices, in the batched graph, of the dynamic vertex nodes of each scene graph."""
    rows, offset = [], 0
    for scene_graph in scene_graphs:
        rows.append(torch.arange(scene_graph.num_dynamic_vertex_nodes) + offset)
        offset += scene_graph.graph.num_nodes
    return torch.cat(rows)


def check_trainable(data, where) -> None:
    """A FignetError for data that holds nothing to learn from: a training example needs frames
    t−1, t and t+1 and an object that moves."""
    short = [key for key, t in data.trajectories.items() if t.num_frames < 3]
    if short:
        raise FignetError(
            f"{where}: trajectory {short[0]!r} has {data.trajectories[short[0]].num_frames} frames"
            f"{f' ({len(short)} such)' if len(short) > 1 else ''}; training needs 3 or more (t-1, t, t+1) in each"
        )
    if not any(not np.all(t.static) for t in data.trajectories.values()):
        raise FignetError(f"{where}: no trajectory has a dynamic object; there is no motion to learn")


def make_trainer(
    dataset_path,
    simulator_config,
    training_config,
    device="cpu",
    resume_from=None,
    init_from=None,
    workers=0,
    scene_cache=None,
):
    """A Trainer for a dataset; resumed from a checkpoint's model and training state if given,
    or a new run that starts from the weights and normalizer statistics of `init_from`. Each
    process keeps at most `scene_cache` of its Scenes made (None: all; `SceneStore`; `train`: 4096)."""
    dataset_path = Path(dataset_path)
    data = read_trajectories(dataset_path)  # a clear error for a missing or damaged file, before hashing it
    check_trainable(data, dataset_path)
    data_hash = file_sha256(dataset_path)
    inertia_added = False  # columns grafted onto an init_from model, whose statistics are still to be set
    if resume_from is not None:
        simulator, state = load_checkpoint(resume_from, with_training_state=True)
        if state is None:
            raise FignetError(f"{resume_from}: holds no training state to resume from (an exported model?)")
        if state["data_hash"] != data_hash:
            raise FignetError(
                f"{resume_from}: was trained on other data than {dataset_path}; start a new run"
            )
        stored = {
            "target_keeps_noise": False,
            **json.loads(state["training_config"]),
        }  # absent: a run before the field (precision too)
        training_config = TrainingSettings(**{**stored, "steps": training_config.steps})
    if resume_from is None:
        simulator_config = dataclasses.replace(
            simulator_config, dt=float(data.dt), gravity=tuple(float(g) for g in data.gravity)
        )
        with torch.random.fork_rng():  # weights drawn from the run's seed, global state untouched
            torch.manual_seed(training_config.seed)
            simulator, state = LearnedSimulator(simulator_config), None
        if init_from is not None:
            blocks, inertia_added = _load_weights(simulator, init_from)
            if blocks < simulator.config.network.message_passing_steps:
                training_config = dataclasses.replace(training_config, added_blocks_from=blocks)
        if training_config.added_blocks_learning_rate_scale != 1.0 and not training_config.added_blocks_from:
            raise FignetError(
                "the added blocks' learning rate scale applies to processor blocks added to a trained "
                "model: give `init_from` a model of fewer blocks than `message_passing_steps`"
            )
    if training_config.unroll < 1:
        raise FignetError(f"unroll = {training_config.unroll}: the loss follows at least 1 step")
    if training_config.unroll > 1:
        check_unrollable(simulator.config)
        if distributed.world_size() > 1:
            raise FignetError("a loss through several steps runs in one process; train it without torchrun")
        if training_config.pushforward:
            raise FignetError(
                "a loss through several steps already starts each later step from the model's own "
                "answer; train it without pushforward examples"
            )
    if training_config.velocity_weight != 1.0 and not simulator.config.uses_velocities:
        raise FignetError("a velocity weight needs a velocity-state model, whose output has velocity columns")
    if simulator.config.uses_velocities and not all(t.has_velocities for t in data.trajectories.values()):
        raise FignetError(
            f"{dataset_path}: has no recorded velocities (a format version 1 file), which a velocity-state "
            "model learns from; make it again with `fignetctl make-dataset`"
        )
    scenes = SceneStore(data, simulator.config, TRAINING_STATIC_REACH, scene_cache)
    if inertia_added:
        fill_inertia_statistics(simulator, scenes, training_config.seed)
    trainer = Trainer(scenes, simulator, training_config, device, data_hash, workers)
    if state is not None:
        trainer.load_state(state)
    return trainer


def _load_weights(simulator, path) -> tuple[int, bool]:
    """Copy a model file's weights and normalizer statistics into `simulator`, or a clear
    error when its network differs (another architecture or size) or it reads mass with the
    other feature (kg or log), or its face-face edges differ in `contact_velocity`, or it
    decodes the whole correction where this run decodes the change from free motion, or the
    other way round (`free_motion`). A source of the same widths but fewer processor blocks
    fills the first ones; the blocks after them start as identity (`network.silence`), so the
    run starts from the source's predictions. So does a source of narrower MLP hidden layers,
    whose units keep their weights beside the added ones (`network.mlp_widened`), a FIGNet run
    from a FIGNet* source, whose surface edges' messages start shut out (`surface_edges_grafted`),
    and a run with `inertia` from a source without it (`inertia_grafted`). Returns the source's
    processor blocks and whether the inertia columns were added (their statistics are still to be
    set)."""
    source = load_checkpoint(path)
    if source.config.graph.log_mass != simulator.config.graph.log_mass:
        feature = "log" if source.config.graph.log_mass else "kg"
        raise FignetError(
            f"{path}: it reads mass as {feature}, so its weights and statistics fit that feature; "
            f"give the same `mass_feature` ({feature})"
        )
    if source.config.graph.contact_velocity != simulator.config.graph.contact_velocity:
        trained = "with" if source.config.graph.contact_velocity else "without"
        raise FignetError(f"{path}: it was trained {trained} `contact_velocity`; give this run the same")
    if source.config.graph.inertia and not simulator.config.graph.inertia:
        raise FignetError(f"{path}: it was trained with `inertia`; give this run the same")
    if source.config.free_motion != simulator.config.free_motion:
        trained = "with" if source.config.free_motion else "without"
        raise FignetError(f"{path}: it was trained {trained} `free_motion`; give this run the same")
    own, given = simulator.config.network, source.config.network
    blocks = given.message_passing_steps
    grown_to_own = dataclasses.replace(
        given, message_passing_steps=own.message_passing_steps, mlp_hidden_size=own.mlp_hidden_size
    )
    fits = grown_to_own == own and own.mlp_hidden_size >= given.mlp_hidden_size
    grown = own.message_passing_steps > blocks and fits
    grafted = simulator.config.graph.surface_edges and not source.config.graph.surface_edges
    weights = surface_edges_grafted(source.state_dict(), simulator) if grafted else source.state_dict()
    inertia_added = simulator.config.graph.inertia and not source.config.graph.inertia
    if inertia_added:
        weights = inertia_grafted(weights)
    if own.mlp_hidden_size > given.mlp_hidden_size and fits:
        weights = mlp_widened(weights, simulator.state_dict())
    try:
        missing, unexpected = simulator.load_state_dict(weights, strict=not (grown or grafted))
        new_blocks = tuple(f"network.processor.{k}." for k in range(blocks, own.message_passing_steps))
        added = [
            key for key in missing if not key.startswith(new_blocks) and not (grafted and NODE_NODE in key)
        ]
        if unexpected or added:
            raise RuntimeError(f"the model file's weights do not fit: {[*unexpected, *added][0]}")
        for block in simulator.network.processor[blocks:]:  # after the source's blocks: identity
            silence(block)
    except RuntimeError as error:
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        detail = lines[1] if lines[0].endswith(":") and len(lines) > 1 else lines[0]  # torch's heading
        raise FignetError(
            f"{path}: its network differs from the one asked for (`model`, `size`, "
            f"`message_passing_steps`, `mlp_hidden_size`); give the same ones ({detail})"
        ) from None
    return blocks, inertia_added


def surface_edges_grafted(weights: dict, simulator) -> dict:
    """A FIGNet* model's `weights` widened to `simulator`'s FIGNet, which also passes messages
    along each mesh's surface edges (node_node): each node update's first layer takes the
    source's columns for the node latent and the edge sets both have, and zeros for the
    node_node messages, so the network predicts what the source does. The node_node encoder,
    edge updates and normalizer keep `simulator`'s initialisation: the messages flow from the
    start and the zero columns, which get their gradients, let them in (as zero-initialised
    adapters do)."""
    names = simulator.network.signature.edge_set_names  # the node update's message order
    source_names = [name for name in names if name != NODE_NODE]
    latent = simulator.config.network.latent_size
    widened = dict(weights)
    for key, value in weights.items():
        if key.endswith("node_update.0.0.weight"):
            parts = dict(zip(["node", *source_names], value.split(latent, dim=1), strict=True))
            parts[NODE_NODE] = torch.zeros_like(parts["node"])
            widened[key] = torch.cat([parts[name] for name in ["node", *names]], dim=1)
    return widened


def inertia_grafted(weights: dict) -> dict:
    """A model's `weights` widened to read the object nodes' inertia (GraphConfig.inertia): the
    node encoder's first layer gets zero columns for the nine inputs, so the network predicts
    what the source does and the columns, which get their gradients, let the inertia in; the
    node normalizer's sums get zeros there, for `fill_inertia_statistics` to set."""
    widened = dict(weights)
    weight = weights["network.node_encoder.0.0.weight"]
    widened["network.node_encoder.0.0.weight"] = torch.cat(
        [weight, weight.new_zeros(weight.shape[0], INERTIA_FEATURE_SIZE)], dim=1
    )
    for key in ("node_normalizer.sum", "node_normalizer.sum_of_squares"):
        widened[key] = torch.cat([weights[key], weights[key].new_zeros(INERTIA_FEATURE_SIZE)])
    return widened


def fill_inertia_statistics(simulator, scenes, seed: int, samples: int = 256) -> None:
    """Set the node normalizer's sums for the inertia columns that `inertia_grafted` added, from
    the graphs of `samples` random training frames, as if they had been accumulated with the
    rest (the statistics count every node row the source has seen)."""
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(seed)
    config = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    columns = []
    for _ in range(samples):
        scene = scenes[int(rng.integers(len(scenes)))]
        frame = int(rng.integers(1, len(scene.positions) - 1))
        scene_graph, _ = training_example(simulator.config, scene, frame, generator, config)
        columns.append(scene_graph.graph.node_features[:, NODE_FEATURE_SIZE:].double())
    rows = torch.cat(columns)
    normalizer = simulator.node_normalizer
    normalizer.sum[NODE_FEATURE_SIZE:] = normalizer.count * rows.mean(dim=0)
    normalizer.sum_of_squares[NODE_FEATURE_SIZE:] = normalizer.count * (rows * rows).mean(dim=0)


def simulator_config_for(
    architecture,
    size,
    collision_radius=None,
    max_faces=256,
    max_static_edge=None,
    max_vertex_offset=1.0,
    speculative=False,
    state="positions",
    static_receivers=True,
    log_mass=False,
    decimation="closest",
    contact_velocity=False,
    free_motion=False,
    message_passing_steps=None,
    inertia=False,
    mlp_hidden_size=None,
) -> SimulatorConfig:
    """The SimulatorConfig of a command line: 'fignet-star' or 'fignet', a network preset (with
    its processor blocks and hidden width, unless `message_passing_steps` or `mlp_hidden_size`
    is given), the state."""
    from fignetctl.core.model.network import PRESETS
    from fignetctl.core.model.scene_graph import GraphConfig
    from fignetctl.core.model.simulator import output_size_for

    graph = GraphConfig(
        surface_edges=architecture == "fignet",
        max_vertex_offset=max_vertex_offset,
        speculative=speculative,
        static_receivers=static_receivers,
        log_mass=log_mass,
        contact_velocity=contact_velocity,
        inertia=inertia,
    )
    if collision_radius is not None:
        graph = dataclasses.replace(graph, collision_radius=collision_radius)
    network = dataclasses.replace(PRESETS[size], output_size=output_size_for(state))
    if message_passing_steps is not None:
        network = dataclasses.replace(network, message_passing_steps=message_passing_steps)
    if mlp_hidden_size is not None:
        network = dataclasses.replace(network, mlp_hidden_size=mlp_hidden_size)
    return SimulatorConfig(
        network=network,
        graph=graph,
        max_faces_per_object=max_faces,
        decimation=decimation,
        max_static_edge=max_static_edge,
        state=state,
        free_motion=free_motion,
    )


def write_loss_csv(path, history) -> None:
    """step, loss, seconds per row, written atomically."""
    from fignetctl.core.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write("step,loss,seconds\n")
        f.writelines(f"{h['step']},{h['loss']:.6g},{h['seconds']:.3f}\n" for h in history)
