#!/usr/bin/env python3
"""Where a fit's held-out error lies in BRDF configuration space: the squared error of a fit on
held-out samples, binned by the half-vector angle theta_h (from the normal) and the difference
angle theta_d (between the light and the half vector), Rusinkiewicz's parameterisation
(bench/RESULTS.md, "Where suzanne's held-out error is").

    reflcap resample CAPTURE --split holdout --out HOLDOUT_SAMPLES
    PYTHONPATH=build/python python3 bench/error_by_configuration.py HOLDOUT_SAMPLES FIT [--json OUT]

HOLDOUT_SAMPLES is a sample store of the photographs the fit did not see (any split works: a
store of the train split gives the in-sample error), FIT a `reflcap fit` output over the same
atlas. Each sample's error is (y - f(wi, wo)) cos(theta_i) per channel: the BRDF error times the
cosine factor of its irradiance, so bins weigh as the re-rendered radiance does when every lamp
has the same intensity and distance (a turntable rig); lamps of different intensity are not
weighed by it. It prints, per bin, the samples, their share of the squared error, and the mean
measured and predicted BRDF value. Reads the store chunk by chunk: memory stays at one chunk.
"""
import argparse
import json
import os
import sys

import numpy as np

import reflcap

# Bin edges in degrees. theta_d: a glossy dielectric's Fresnel reflectance and the microfacet
# 1 / (4 cos theta_i cos theta_o) factor grow fast beyond 60 degrees, so the edges are denser
# there. theta_h: 10 degrees from the normal puts the view 20 degrees from the mirror direction,
# where a lobe of n = 30 has fallen to 0.16 of its peak: the split separates a highlight's
# neighbourhood from the rest for the lobes suzanne's fit keeps (cluster lobes n = 40-350).
THETA_D_EDGES = [0, 30, 50, 60, 70, 90]
THETA_H_NEAR_DEG = 10.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("samples", help="sample store (reflcap resample --out)")
    ap.add_argument("fit", help="FIT folder (reflcap fit --out) over the same atlas")
    ap.add_argument("--json", help="also write the table as JSON to this file")
    args = ap.parse_args()

    info = reflcap.read_store_info(args.samples)
    fit = reflcap.read_fit(args.fit)
    atlas = info["atlas"]
    if (atlas["width"], atlas["height"]) != (fit["width"], fit["height"]):
        sys.exit(f"error: {args.fit}: params.exr is {fit['width']} x {fit['height']}, the store's "
                 f"atlas {atlas['width']} x {atlas['height']}: not the same atlas")
    params = fit["params"].reshape(-1, fit["params"].shape[2])
    pixel_of_texel = atlas["pixel_of_texel"]

    nd = len(THETA_D_EDGES) - 1
    count = np.zeros((nd, 2), np.int64)
    sq = np.zeros((nd, 2))
    measured = np.zeros((nd, 2))
    predicted = np.zeros((nd, 2))
    reference = 0.0  # sum of (y cos theta_i)^2: the relative error's denominator
    for index in range(info["chunks"]):
        chunk = reflcap.read_chunk(args.samples, index)
        wi, wo, y, w = chunk["wi"], chunk["wo"], chunk["value"], chunk["weight"]
        # The fit's own mask: both directions above the store's grazing limit, positive weight
        # and finite values (a zeroed or rejected record says nothing).
        ok = ((wi[:, 2] > info["min_cos"]) & (wo[:, 2] > info["min_cos"]) &
              np.all(w > 0, axis=1) & np.all(np.isfinite(y), axis=1))
        if not ok.any():
            continue
        wi, wo, y = wi[ok], wo[ok], y[ok]
        f = reflcap.eval_brdf(params[pixel_of_texel[chunk["texel"][ok]]], wi, wo)
        h = wi + wo
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        # Clipped to [-1, 1] before arccos: rounding can leave a unit dot product 1 ulp above 1.
        theta_d = np.degrees(np.arccos(np.clip(np.sum(wi * h, axis=1), -1.0, 1.0)))
        near = h[:, 2] >= np.cos(np.radians(THETA_H_NEAR_DEG))
        d_bin = np.clip(np.searchsorted(THETA_D_EDGES, theta_d, side="right") - 1, 0, nd - 1)
        cos_i = wi[:, 2:3]
        err = np.sum(((y - f) * cos_i) ** 2, axis=1)
        reference += float(np.sum((y * cos_i) ** 2))
        for b in range(nd):
            for j, sel in enumerate((near, ~near)):
                m = (d_bin == b) & sel
                count[b, j] += int(m.sum())
                sq[b, j] += float(err[m].sum())
                measured[b, j] += float(y[m].mean(axis=1).sum())
                predicted[b, j] += float(f[m].mean(axis=1).sum())

    total = sq.sum()
    if count.sum() == 0 or total <= 0:
        sys.exit(f"error: {args.samples}: no usable sample")
    rows = []
    print(f"samples {count.sum()}, relative error sqrt(sum err^2 / sum (y cos)^2) "
          f"{np.sqrt(total / reference):.4f}")
    print(f"{'theta_d':>9} {'theta_h':>8} {'samples':>10} {'share':>7} {'mean y':>8} {'mean f':>8}")
    for b in range(nd):
        for j, name in enumerate((f"< {THETA_H_NEAR_DEG:g}", f">= {THETA_H_NEAR_DEG:g}")):
            n = int(count[b, j])
            row = {"theta_d_deg": [THETA_D_EDGES[b], THETA_D_EDGES[b + 1]],
                   "theta_h_near": j == 0, "samples": n, "error_share": sq[b, j] / total,
                   "mean_measured": measured[b, j] / n if n else None,
                   "mean_predicted": predicted[b, j] / n if n else None}
            rows.append(row)
            mean_y = f"{row['mean_measured']:8.3f}" if n else f"{'-':>8}"
            mean_f = f"{row['mean_predicted']:8.3f}" if n else f"{'-':>8}"
            print(f"{THETA_D_EDGES[b]:>3}-{THETA_D_EDGES[b + 1]:<3}   {name:>8} {n:>10} "
                  f"{row['error_share']:7.3f} {mean_y} {mean_f}")
    if args.json:
        with open(args.json + ".tmp", "w") as out:
            json.dump({"samples": args.samples, "fit": args.fit,
                       "relative_error": float(np.sqrt(total / reference)), "bins": rows},
                      out, indent=1)
        os.replace(args.json + ".tmp", args.json)


if __name__ == "__main__":
    main()
