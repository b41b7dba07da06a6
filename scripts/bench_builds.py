#!/usr/bin/env python3
"""Two builds of fishprobe side by side: the benchmarks that matter, alternating A and B in
one run, so that both see the same machine state (this machine's speed varies by a third from
day to day and within an hour). docs/validation.md, "How long the install takes", shows its
output.

For each round it runs, for A then B (then B then A in the next round, to cancel drift):
  fishprobe bench sim --json
  fishprobe bench train --iterations 4 --json                (M_Zone)
  fishprobe bench train --iterations 4 --model ConvNet --json
  fishprobe bench stats --json
  fishprobe simulate --model onnx:CONVNET.onnx --minutes 60  (an ONNX fish, timed: seconds)
and prints, per number, the median of the rounds for A and B, B's change in per cent, and the
range of B/A over the rounds (each round's A and B ran back to back, so their ratio is what
drift disturbs least).

  python3 scripts/bench_builds.py OLD/bin/fishprobe NEW/bin/fishprobe --rounds 3
"""
import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time

BENCHES = {
    "sim": ["bench", "sim", "--json"],
    "train Zone": ["bench", "train", "--iterations", "4", "--json"],
    "train ConvNet": ["bench", "train", "--iterations", "4", "--model", "ConvNet", "--json"],
    "stats": ["bench", "stats", "--json"],
    "onnx fish": "onnx fish",
}


def numbers(prefix, value, out):
    """Every number of a JSON document, by its path (rates and times alike)."""
    if isinstance(value, dict):
        for k, v in value.items():
            numbers(f"{prefix}.{k}" if prefix else k, v, out)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            numbers(f"{prefix}[{i}]", v, out)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        out[prefix] = float(value)


def run(binary, args, scratch):
    if args == "onnx fish":
        # M_ConvNet exported by this build and simulated as an ONNX fish: the engine's speed.
        onnx = os.path.join(scratch, os.path.basename(os.path.dirname(binary)) + ".onnx")
        if not os.path.exists(onnx):
            subprocess.run([binary, "export", "--convnet", "--onnx", onnx], check=True,
                           capture_output=True)
        t = time.perf_counter()
        subprocess.run([binary, "simulate", "--model", "onnx:" + onnx, "--minutes", "60",
                        "--out", os.path.join(scratch, "trial.hdf5")], check=True,
                       capture_output=True)
        return {"simulate_seconds": time.perf_counter() - t}
    o = subprocess.run([binary, *args], check=True, capture_output=True, text=True)
    out = {}
    numbers("", json.loads(o.stdout), out)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", help="the first build's fishprobe binary (the reference)")
    ap.add_argument("b", help="the second build's fishprobe binary")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--only", nargs="*", choices=list(BENCHES), help="a subset of the benches")
    ap.add_argument("--keys", nargs="*", help="print only numbers whose path contains one of these")
    args = ap.parse_args()
    seen = {name: {"a": [], "b": []} for name in BENCHES}
    scratch = tempfile.mkdtemp(prefix="bench_builds")
    for r in range(args.rounds):
        order = ["a", "b"] if r % 2 == 0 else ["b", "a"]
        for name, bench in BENCHES.items():
            if args.only and name not in args.only:
                continue
            for side in order:
                seen[name][side].append(run(getattr(args, side), bench, scratch))
    print("| bench | number | A (median) | B (median) | B vs A | B/A by round |")
    print("|---|---|---|---|---|---|")
    for name, sides in seen.items():
        if not sides["a"]:
            continue
        for key in sides["a"][0]:
            if args.keys and not any(k in key for k in args.keys):
                continue
            a = statistics.median(x[key] for x in sides["a"] if key in x)
            b = statistics.median(x[key] for x in sides["b"] if key in x)
            change = f"{100 * (b - a) / a:+.1f} %" if a else "-"
            ratios = [y[key] / x[key] for x, y in zip(sides["a"], sides["b"])
                      if x.get(key) and key in y]
            spread = f"{min(ratios):.3f}-{max(ratios):.3f}" if ratios else "-"
            print(f"| {name} | {key} | {a:.4g} | {b:.4g} | {change} | {spread} |")


if __name__ == "__main__":
    main()
