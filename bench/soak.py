#!/usr/bin/env python3
"""Soak: one long-lived process fits a whole sample store again and again, and renders a view
from each round's fit; its memory must stay flat (README.md, "Hardening").

    PYTHONPATH=build/python python3 bench/soak.py SAMPLES CAPTURE [--rounds N] [--backend cpu]

SAMPLES is a sample store (`reflcap resample`), CAPTURE its capture. Every round reads every chunk
and fits it (`reflcap.fit_samples`, results checked finite and dropped), then, with --fit FIT (a
`reflcap fit` output of the same store), renders image 0 of the capture from it. After each round
it prints the process's resident set (VmRSS, after malloc_trim) and its peak (VmHWM). The verdict
compares the last round's RSS with the one a third into the run (the first rounds grow the
allocators' pools to their working size): growth beyond --max-growth-percent (default 5) fails
with exit 1, as does a non-finite value.
"""
import argparse
import ctypes
import sys
import time

import numpy as np

import reflcap


def rss_kib():
    # Freed memory that glibc's allocator keeps in its arenas would read as growth (RSS moved by
    # +-15 % between rounds without it): hand it back first, so what remains is live memory.
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    fields = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                fields[key] = int(value.split()[0])
    return fields["VmRSS"], fields["VmHWM"]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("samples")
    p.add_argument("capture")
    p.add_argument("--fit", help="a FIT folder of the same capture, rendered from each round")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--backend", default="cpu")
    p.add_argument("--max-growth-percent", type=float, default=5.0)
    args = p.parse_args()

    info = reflcap.read_store_info(args.samples)
    print(f"store: {info['texels']} texels, {info['chunks']} chunks; backend {args.backend}", flush=True)
    history = []
    for r in range(args.rounds):
        t0 = time.time()
        fitted = converged = 0
        finite = True
        for c in range(info["chunks"]):
            chunk = reflcap.read_chunk(args.samples, c)
            if chunk["value"].shape[0] == 0:
                continue
            out = reflcap.fit_samples(chunk["wi"], chunk["wo"], chunk["value"], weight=chunk["weight"],
                                      texel=chunk["texel"] - chunk["first_texel"], backend=args.backend)
            fitted += out["params"].shape[0]
            converged += int(np.count_nonzero(out["status"] == 0))
            finite &= bool(np.isfinite(out["params"]).all()) and bool(np.isfinite(out["sigma"]).all())
        rendered = ""
        if args.fit:
            pixels = reflcap.render_view(args.capture, args.fit, 0)
            finite &= bool(np.isfinite(pixels).all())
            rendered = f", rendered {pixels.shape[1]}x{pixels.shape[0]}"
        rss, hwm = rss_kib()
        history.append(rss)
        print(f"round {r + 1}: {fitted} texels fitted ({converged} converged){rendered} in "
              f"{time.time() - t0:.1f} s; RSS {rss / 1024:.1f} MiB, peak {hwm / 1024:.1f} MiB; "
              f"finite {finite}", flush=True)
        if not finite:
            print("soak: a non-finite value escaped", file=sys.stderr)
            return 1
    if len(history) >= 3:
        # The reference round: a third into the run (at least the second). The first rounds grow
        # the allocators' pools (TBB's and Embree's, behind render_view) to their working size.
        ref = max(1, len(history) // 3)
        growth = 100.0 * (history[-1] - history[ref]) / history[ref]
        print(f"RSS growth from round {ref + 1} to round {len(history)}: {growth:+.2f} % "
              f"(limit {args.max_growth_percent} %)")
        if growth > args.max_growth_percent:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
