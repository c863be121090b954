"""Every command on the whole fuzzing corpus (tests/fuzz_corpus.py): counts per outcome.

    python benchmarks/fuzz_commands.py --flips 32 -o benchmarks/results/fuzz-commands.json

Prints the counts (clean errors, successes, tracebacks, messy errors, outputs left behind,
hangs) per command and overall, the cases that were not clean or successes, and writes them
to json.
"""

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' corpus and helpers

from fignetctl.core.atomic import write_json
from tests.fuzz_corpus import OUTCOMES, base_files, corpus, run_case


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flips", type=int, default=32, help="byte-flip variants per input")
    parser.add_argument("--timeout", type=int, default=120, help="seconds before a case is a hang")
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args()
    cases = corpus(flips=args.flips)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fuzz-") as work:
        base = base_files(Path(work) / "base")
        results = []
        for index, case in enumerate(cases):
            results.append(run_case(case, base, Path(work) / f"case{index}", args.timeout))
            if (index + 1) % 100 == 0:
                print(
                    f"{index + 1}/{len(cases)} cases, {time.perf_counter() - started:.0f} s", file=sys.stderr
                )
    by_command = collections.defaultdict(collections.Counter)
    for result in results:
        by_command[result["case"].split(":")[0]][result["outcome"]] += 1
    total = collections.Counter(r["outcome"] for r in results)
    report = {
        "cases": len(results),
        "seconds": round(time.perf_counter() - started, 1),
        "outcomes": {outcome: total[outcome] for outcome in OUTCOMES},
        "per_command": {name: dict(counts) for name, counts in sorted(by_command.items())},
        "not_clean": [r for r in results if r["outcome"] not in ("clean", "success")],
        "successes": [r["case"] for r in results if r["outcome"] == "success"],
    }
    print(json.dumps({k: report[k] for k in ("cases", "seconds", "outcomes", "per_command")}, indent=1))
    for result in report["not_clean"]:
        print(result, file=sys.stderr)
    if args.output:
        write_json(args.output, report)


if __name__ == "__main__":
    main()
