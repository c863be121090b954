"""The bundled FIGNet and FIGNet* averaged, two ways, on held-out trajectories.

Both bundled models went on from one model (stage 14's end) with the same recipe, FIGNet with
its surface edges grafted on (docs/simulator.md, "The bundled checkpoints"), so they can be
averaged in weight space as well as in their answers:

- `soup`: one FIGNet whose weights are (1 − w) × FIGNet's + w × FIGNet*'s, the FIGNet*'s node
  updates widened with zero columns for the surface-edge messages (`surface_edges_grafted`),
  its surface-edge encoder and edge updates FIGNet's own, written to --model-out and evaluated;
- `ensemble`: both networks run on every step's graph (FIGNet*'s without the surface edges),
  their accelerations averaged.

    python benchmarks/pair_average.py soup data/movi-b-test.h5 --model-out soup.pt -o soup.json
    python benchmarks/pair_average.py ensemble data/movi-b-test.h5 -o ensemble.json

Each json is `fignetctl evaluate`'s, network alone, at the models' four turns.
"""

import argparse

import torch

from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import evaluate_trajectories, load_model
from fignetctl.core.model.checkpoint import (
    bundled_model_path,
    load_checkpoint,
    read_checkpoint_payload,
    save_torch_payload,
)
from fignetctl.core.model.graph import NODE_NODE, MultiGraph
from fignetctl.core.model.training import surface_edges_grafted
from fignetctl.core.trajectory import read_trajectories


def soup_payload(fignet_path, star_path, star_weight=0.5) -> dict:
    """The FIGNet model file's contents with its weights averaged with the FIGNet*'s."""
    fignet, star = read_checkpoint_payload(fignet_path), read_checkpoint_payload(star_path)
    widened = surface_edges_grafted(star["model"], load_checkpoint(fignet_path))
    weights = {
        name: (1 - star_weight) * value + star_weight * widened[name]
        if name in widened and value.is_floating_point()
        else value
        for name, value in fignet["model"].items()
    }
    return {key: value for key, value in fignet.items() if key != "training_state"} | {"model": weights}


def ensemble(fignet, star):
    """`fignet` (a LearnedSimulator) made to answer with the mean of its own and `star`'s
    accelerations; star reads the same graph without its surface edges."""
    own = fignet.network_acceleration

    def averaged(graph: MultiGraph) -> torch.Tensor:
        without = {name: edges for name, edges in graph.edge_sets.items() if name != NODE_NODE}
        return 0.5 * (own(graph) + star.network_acceleration(MultiGraph(graph.node_features, without)))

    fignet.network_acceleration = averaged
    return fignet


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("method", choices=("soup", "ensemble"))
    parser.add_argument("data", help="held-out trajectory file")
    parser.add_argument("-n", type=int, default=None, help="the first n trajectories (default: all)")
    parser.add_argument("--star-weight", type=float, default=0.5, help="soup: the FIGNet*'s share")
    parser.add_argument("--model-out", help="soup: write the averaged model file here")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    paths = bundled_model_path("fignet-movi-b"), bundled_model_path("fignet-star-movi-b")
    if args.method == "soup":
        if not args.model_out:
            parser.error("soup: give --model-out")
        save_torch_payload(args.model_out, soup_payload(*paths, args.star_weight))
        simulator = load_model(args.model_out)
    else:
        simulator = ensemble(load_model("fignet-movi-b"), load_model("fignet-star-movi-b"))
    metrics = evaluate_trajectories(simulator, read_trajectories(args.data), args.n, where=args.data)
    write_json(args.output, {"method": args.method, "star_weight": args.star_weight, **metrics}, indent=2)
    print(args.output)


if __name__ == "__main__":
    main()
