"""Run a command and sample the resident memory of it and of each of its descendants.

Writes the samples and the peaks to a json file and prints the peaks: the command's own
process, its largest descendant, and all of them together. Linux (/proc).

    python benchmarks/process_memory.py memory.json -- \\
        fignetctl train data/movi-b-train-16000.h5 -o model.pt --steps 1500 --workers 1
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from fignetctl.core.atomic import write_json


def descendants(pid: int) -> list[int]:
    try:
        children = [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    return [p for c in children for p in (c, *descendants(c))]


def resident_gb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1e6
    except OSError:
        pass
    return 0.0


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("output", type=Path, help="json file of samples and peaks")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between samples")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to run after --")
    started = time.monotonic()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    samples = []
    while process.poll() is None:
        others = sorted((resident_gb(p) for p in descendants(process.pid)), reverse=True)
        samples.append(
            {
                "seconds": round(time.monotonic() - started, 1),
                "command_gb": resident_gb(process.pid),
                "descendants_gb": others,
            }
        )
        time.sleep(args.interval)
    result = {
        "command": command,
        "exit_code": process.returncode,
        "seconds": round(time.monotonic() - started, 1),
        "peak_command_gb": round(max((s["command_gb"] for s in samples), default=0.0), 2),
        "peak_largest_descendant_gb": round(
            max((s["descendants_gb"][0] for s in samples if s["descendants_gb"]), default=0.0), 2
        ),
        "peak_total_gb": round(
            max((s["command_gb"] + sum(s["descendants_gb"]) for s in samples), default=0.0), 2
        ),
        "samples": samples,
    }
    write_json(args.output, result)
    print(json.dumps({k: v for k, v in result.items() if k != "samples"}))
    sys.exit(process.returncode)


if __name__ == "__main__":
    main()
