"""Checks issue 39's claims on two reports of the same corpus (jitter known, jitter unknown)
and prints them as a markdown table: phlm against taa on the mean and per scene (PSNR and
tRMSE), taa with the jitter known against each pixel's own sample (`taa:pixel_filter=box`)
on the aliasing scenes, and traa against its baseline. Both reports need the filters
taa, phlm, traa, taa:pixel_filter=box and traa:variant=baseline.

    python3 corpus/claims.py KNOWN/report.json UNKNOWN/report.json
"""

import json
import sys

ALIASING = ["cut", "fence", "foliage", "movers", "pan", "texture"]


def load(path):
    r = json.load(open(path))
    cells = {(s["scene"], c["filter"]): c for s in r["scenes"] for c in s["cells"]}
    return [s["scene"] for s in r["scenes"]], cells


def mean(scenes, cells, f, key="mean_psnr"):
    return sum(cells[(s, f)][key] for s in scenes) / len(scenes)


def phlm_rows(scenes, cells):
    lead = mean(scenes, cells, "phlm") - mean(scenes, cells, "taa")
    t_phlm, t_taa = (mean(scenes, cells, f, "trmse") for f in ("phlm", "taa"))
    per = sorted((cells[(s, "phlm")]["mean_psnr"] - cells[(s, "taa")]["mean_psnr"], s) for s in scenes)
    worst = ", ".join(f"`{s}` {d:+.2f}" for d, s in per[:2])
    return (f"{lead:+.2f}" + (" ✓" if lead >= 0.5 else " ✗"),
            f"{t_phlm:.4f} vs {t_taa:.4f}" + (" ✓" if t_phlm < t_taa else " ✗"),
            worst + (" ✓" if per[0][0] >= -0.3 else " ✗"))


def main():
    (scenes, known), (_, unknown) = load(sys.argv[1]), load(sys.argv[2])
    k, u = phlm_rows(scenes, known), phlm_rows(scenes, unknown)
    print("| claim (issue 39) | jitter known | jitter unknown |")
    print("|---|---|---|")
    print(f"| phlm >= taa + 0.5 dB on the mean | {k[0]} | {u[0]} |")
    print(f"| phlm's tRMSE below taa's | {k[1]} | {u[1]} |")
    print(f"| no scene with phlm more than 0.3 dB below taa (the two lowest) | {k[2]} | {u[2]} |")
    al = [s for s in scenes if s in ALIASING]
    per = [known[(s, "taa")]["mean_psnr"] - known[(s, "taa:pixel_filter=box")]["mean_psnr"] for s in al]
    gain = sum(per) / len(per)
    each = ", ".join(f"`{s}` {d:+.2f}" for s, d in zip(al, per))
    print(f"| taa, jitter known, >= taa blind (`pixel_filter=box`) + 0.1 dB on the aliasing scenes "
          f"| {gain:+.2f} on their mean{' ✓' if gain >= 0.1 else ' ✗'} ({each}) | (not applicable) |")
    for name, cells in (("known", known), ("unknown", unknown)):
        worse = [s for s in scenes if cells[(s, "traa")]["mean_psnr"] <= cells[(s, "traa:variant=baseline")]["mean_psnr"]]
        t, b = mean(scenes, cells, "traa"), mean(scenes, cells, "traa:variant=baseline")
        print(f"| traa improved >= its baseline, jitter {name} | {t:.2f} vs {b:.2f}"
              f"{', below on ' + ', '.join(worse) if worse else ', every scene'} | |")


main()
