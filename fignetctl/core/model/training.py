"""Training a learned simulator on a trajectory file, with exact resume.

Each step draws `batch_size` examples (a trajectory and a frame t with t−1 and t+1 around
it), jitters the pose of every dynamic object at t (noise.py), builds each graph, and
regresses the normalised accelerations of the dynamic mesh nodes with an MSE loss. Adam with a
learning rate decaying exponentially from `learning_rate_initial` to `learning_rate_final`.

Everything random comes from one numpy Generator (data) and one torch Generator (noise) whose
states are saved with the weights, so a run resumed from a checkpoint reaches the same weights
as one that never stopped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.model import distributed
from fignetctl.core.model.checkpoint import load_checkpoint, save_checkpoint
from fignetctl.core.model.graph import batch_graphs
from fignetctl.core.model.noise import sample_rigid_pose_noise
from fignetctl.core.model.properties import property_ranges, ranges_to_json
from fignetctl.core.model.scene_graph import build_scene_graph
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_file
from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig
from fignetctl.core.transforms import quat_from_axis_angle, quat_multiply
from fignetctl.errors import FignetError


@dataclasses.dataclass(frozen=True)
class TrainingConfig:
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
    loss: str = "mse"
    """'mse' (the paper) or 'huber' on the normalised accelerations."""
    huber_delta: float = 0.5
    """Where the Huber loss turns from quadratic to linear, in target standard deviations."""
    normalizer_accumulation_steps: int = 500
    """Normaliser statistics are gathered over the first this many steps, then frozen."""
    checkpoint_every: int = 500
    """Steps between checkpoints."""
    seed: int = 0

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


def file_sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def learning_rate_factor(step: int, config: TrainingConfig) -> float:
    """Multiplier of the initial rate at `step`: 1 at 0, final/initial at `steps`."""
    ratio = config.learning_rate_final / config.learning_rate_initial
    return ratio ** (min(step, config.steps) / max(config.steps, 1))


def jitter_frame_t(positions, quaternions, static, generator, config: TrainingConfig):
    """Per-object rigid noise on frame t (index 1) of (3, O, 3) / (3, O, 4) poses; copies."""
    noise = sample_rigid_pose_noise(
        torch.from_numpy(~static), config.noise_translation_std, config.noise_rotation_std, generator
    )
    rotation_vectors = noise.rotation_vectors.double().numpy()
    angles = np.linalg.norm(rotation_vectors, axis=1)
    axes = np.where(angles[:, None] > 0, rotation_vectors / np.maximum(angles, 1e-300)[:, None], [1.0, 0, 0])
    positions, quaternions = positions.copy(), quaternions.copy()
    positions[1] += noise.translations.double().numpy()
    quaternions[1] = quat_multiply(quat_from_axis_angle(axes, angles), quaternions[1])
    return positions, quaternions


def training_example(simulator, scene, frame, generator, config: TrainingConfig):
    """One noisy example: the raw graph and the raw acceleration targets of its dynamic vertices."""
    clean_positions, clean_quaternions = scene.positions[frame - 1 : frame + 2], scene.quaternions[frame - 1 : frame + 2]
    positions, quaternions = jitter_frame_t(clean_positions, clean_quaternions, scene.geometry.static, generator, config)
    scene_graph = build_scene_graph(scene.geometry, positions, quaternions, simulator.config.graph)
    previous, now, after = scene_graph.dynamic_vertex_positions
    if config.target_keeps_noise:
        after = after + now - scene.geometry.world_vertices(clean_positions[1], clean_quaternions[1], scene.geometry.dynamic_vertices)
    acceleration = torch.from_numpy((after - 2.0 * now + previous).astype(np.float32))
    return scene_graph, acceleration


class Trainer:
    """Holds the simulator, optimiser and random state; `run` trains to `config.steps`."""

    def __init__(self, scenes, simulator, config: TrainingConfig, device="cpu", data_hash=""):
        self.rank, device = distributed.join_process_group(device)
        simulator.trained_properties = property_ranges((s.geometry.properties, s.geometry.static) for s in scenes)
        self.scenes, self.simulator, self.config = scenes, simulator.to(device), config
        self.model = distributed.data_parallel(self.simulator, device)
        self.device, self.data_hash = device, data_hash
        self.optimizer = torch.optim.Adam(simulator.parameters(), lr=config.learning_rate_initial)
        self.step = 0
        self.rng = np.random.default_rng([config.seed, self.rank])
        self.noise_generator = torch.Generator().manual_seed(config.seed * 1000 + self.rank)
        self.history = []

    def sample(self):
        """A (scene, frame) pair: frame t has t−1 and t+1 inside the trajectory."""
        scene = self.scenes[self.rng.integers(len(self.scenes))]
        return scene, int(self.rng.integers(1, scene.positions.shape[0] - 1))

    def train_step(self) -> float:
        examples = [training_example(self.simulator, *self.sample(), self.noise_generator, self.config) for _ in range(self.config.batch_size)]
        accumulate = self.step < self.config.normalizer_accumulation_steps
        graph = batch_graphs([e[0].graph for e in examples]).to(self.device)
        rows = _dynamic_rows([e[0] for e in examples]).to(self.device)
        targets = torch.cat([e[1] for e in examples]).to(self.device)
        normalized_targets = self.simulator.inverse_postprocess(targets, accumulate)
        predictions = self.model(graph, accumulate)[rows]
        loss = regression_loss(predictions, normalized_targets, self.config)
        self._apply(loss)
        return float(loss.detach())

    def _apply(self, loss):
        for group in self.optimizer.param_groups:
            group["lr"] = self.config.learning_rate_initial * learning_rate_factor(self.step, self.config)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.step += 1

    def run(self, checkpoint_path=None, on_step=None, until_step=None, on_checkpoint=None):
        """Train until config.steps (or `until_step`), checkpointing every config.checkpoint_every
        steps (and calling `on_checkpoint()` after each checkpoint)."""
        started = time.perf_counter() - (self.history[-1]["seconds"] if self.history else 0.0)
        last_step = self.config.steps if until_step is None else min(until_step, self.config.steps)
        while self.step < last_step:
            loss = self.train_step()
            self.history.append({"step": self.step, "loss": loss, "seconds": time.perf_counter() - started})
            if on_step is not None:
                on_step(self.step, loss)
            if checkpoint_path and (self.step % self.config.checkpoint_every == 0 or self.step == last_step):
                self.save(checkpoint_path)
                if on_checkpoint is not None:
                    on_checkpoint()

    def state(self) -> dict:
        """Everything a resume needs; the random states of every process, in rank order."""
        return {
            "step": self.step,
            "optimizer": self.optimizer.state_dict(),
            "rng": json.dumps(distributed.gather_from_all(self.rng.bit_generator.state)),
            "noise_generator": distributed.gather_from_all(self.noise_generator.get_state()),
            "history": json.dumps(self.history),
            "training_config": self.config.to_json(),
            "data_hash": self.data_hash,
        }

    def load_state(self, state: dict) -> None:
        rng_states = json.loads(state["rng"])
        if len(rng_states) != distributed.world_size():
            raise FignetError(
                f"the checkpoint was written by {len(rng_states)} process(es); resume it with as many"
            )
        self.step = int(state["step"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.rng.bit_generator.state = rng_states[self.rank]
        self.noise_generator.set_state(state["noise_generator"][self.rank])
        self.history = json.loads(state["history"])

    def save(self, path) -> None:
        """Rank 0 writes the checkpoint atomically; the others wait for it."""
        state = self.state()
        if self.rank == 0:
            save_checkpoint(path, self.simulator, training_state=state,
                            extra={"trained_properties": ranges_to_json(self.simulator.trained_properties)})
        distributed.barrier()


def regression_loss(predictions, targets, config: TrainingConfig) -> torch.Tensor:
    """Mean loss over nodes and components of the normalised accelerations."""
    if config.loss == "huber":
        return torch.nn.functional.huber_loss(predictions, targets, delta=config.huber_delta)
    if config.loss == "mse":
        return torch.mean((predictions - targets) ** 2)
    raise FignetError(f"unknown loss {config.loss!r}: choose 'mse' or 'huber'")


def _dynamic_rows(scene_graphs) -> torch.Tensor:
    """Indices, in the batched graph, of the dynamic vertex nodes of each scene graph."""
    rows, offset = [], 0
    for scene_graph in scene_graphs:
        rows.append(torch.arange(scene_graph.num_dynamic_vertex_nodes) + offset)
        offset += scene_graph.graph.num_nodes
    return torch.cat(rows)


def make_trainer(dataset_path, simulator_config, training_config, device="cpu", resume_from=None, init_from=None):
    """A Trainer for a dataset; resumed from a checkpoint's model and training state if given,
    or a new run that starts from the weights and normaliser statistics of `init_from`."""
    dataset_path = Path(dataset_path)
    data_hash = file_sha256(dataset_path)
    if resume_from is not None:
        simulator, state = load_checkpoint(resume_from, with_training_state=True)
        if state is None:
            raise FignetError(f"{resume_from}: holds no training state to resume from (an exported model?)")
        if state["data_hash"] != data_hash:
            raise FignetError(f"{resume_from}: was trained on other data than {dataset_path}; start a new run")
        stored = {"target_keeps_noise": False, **json.loads(state["training_config"])}  # absent: a run before the field
        training_config = TrainingConfig(**{**stored, "steps": training_config.steps})
    else:
        with torch.random.fork_rng():  # weights drawn from the run's seed, global state untouched
            torch.manual_seed(training_config.seed)
            simulator, state = LearnedSimulator(simulator_config), None
        if init_from is not None:
            _load_weights(simulator, init_from)
    scenes = scenes_from_file(dataset_path, simulator.config, TRAINING_STATIC_REACH)
    trainer = Trainer(scenes, simulator, training_config, device, data_hash)
    if state is not None:
        trainer.load_state(state)
    return trainer


def _load_weights(simulator, path) -> None:
    """Copy a model file's weights and normaliser statistics into `simulator`, or a clear
    error when its network differs (another architecture or size)."""
    source = load_checkpoint(path)
    try:
        simulator.load_state_dict(source.state_dict())
    except RuntimeError as error:
        raise FignetError(f"{path}: its network differs from the one asked for (--model, --size); "
                          f"give the same ones ({str(error).splitlines()[0]})") from None


def simulator_config_for(architecture, size, collision_radius=None, max_faces=256, max_static_edge=None, max_vertex_offset=1.0, speculative=False) -> SimulatorConfig:
    """The SimulatorConfig of a command line: 'fignet-star' or 'fignet', a network preset."""
    from fignetctl.core.model.network import PRESETS
    from fignetctl.core.model.scene_graph import GraphConfig

    graph = GraphConfig(surface_edges=architecture == "fignet", max_vertex_offset=max_vertex_offset, speculative=speculative)
    if collision_radius is not None:
        graph = dataclasses.replace(graph, collision_radius=collision_radius)
    return SimulatorConfig(network=PRESETS[size], graph=graph, max_faces_per_object=max_faces, max_static_edge=max_static_edge)


def write_loss_csv(path, history) -> None:
    """step, loss, seconds per row, written atomically."""
    from fignetctl.core.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write("step,loss,seconds\n")
        f.writelines(f"{h['step']},{h['loss']:.6g},{h['seconds']:.3f}\n" for h in history)
