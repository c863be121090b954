"""How much each processor block of a trained model updates its latents: the mean absolute
scale and shift of the LayerNorm that ends each of its updates (edge updates per edge type, and
the node update). A block grown by `train --message-passing-steps` starts with all of them zero
(identity); trained blocks sit near scale 1.

    python benchmarks/block_scales.py MODEL -o block-scales.json
"""

from __future__ import annotations

import argparse
import sys

from fignetctl.core.atomic import write_json
from fignetctl.core.model.checkpoint import load_checkpoint
from fignetctl.core.model.network import PartwiseLayerNorm
from fignetctl.errors import FignetError


def block_scales(simulator) -> list[dict]:
    """Per processor block, {update name: {"scale": mean |weight|, "shift": mean |bias|}}."""
    blocks = []
    for block in simulator.network.processor:
        updates = {}
        for name, module in block.named_modules():
            if isinstance(module, PartwiseLayerNorm):
                norm = module.layer_norm
                update = name.rsplit(".", 1)[0]  # e.g. edge_updates.face_face, node_update
                updates[update] = {
                    "scale": round(norm.weight.abs().mean().item(), 6),
                    "shift": round(norm.bias.abs().mean().item(), 6),
                }
        blocks.append(updates)
    return blocks


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="a model file from `fignetctl train`")
    parser.add_argument("-o", "--output", default=None, help="json to write")
    args = parser.parse_args()
    try:
        blocks = block_scales(load_checkpoint(args.model))
    except FignetError as error:
        sys.exit(f"error: {error}")
    for i, updates in enumerate(blocks):
        scales = ", ".join(f"{k} {v['scale']:.4f}" for k, v in updates.items())
        print(f"block {i}: {scales}")
    if args.output:
        write_json(args.output, {"model": args.model, "blocks": blocks})


if __name__ == "__main__":
    main()
