"""Prints report.json (afterimage report --corpus ...) as two markdown tables: mean PSNR
per filter and scene, then SSIM / tRMSE per filter and scene. With `--upsampling`, the
same for the report's upsampling section.

    python3 corpus/table.py OUT/report.json [--upsampling]
"""

import json
import sys

r = json.load(open(sys.argv[1]))
if "--upsampling" in sys.argv[2:]:
    r = r["upsampling"]
scenes = [s["scene"] for s in r["scenes"]]
filters = [c["filter"] for c in r["scenes"][0]["cells"]]
summary = {s["filter"]: s for s in r["summary"]}


def cell(scene, f):
    return next(c for c in next(s for s in r["scenes"] if s["scene"] == scene)["cells"] if c["filter"] == f)


print("PSNR dB (mean over frames; the mean over scenes last)\n")
print("| filter | " + " | ".join(scenes) + " | **mean** |")
print("|---|" + "---:|" * (len(scenes) + 1))
for f in filters:
    row = [f"{cell(s, f)['mean_psnr']:.2f}" for s in scenes]
    print(f"| {f} | " + " | ".join(row) + f" | **{summary[f]['mean_psnr']:.2f}** |")
print("\nSSIM / tRMSE\n")
print("| filter | " + " | ".join(scenes) + " | **mean** |")
print("|---|" + "---:|" * (len(scenes) + 1))
for f in filters:
    row = []
    for s in scenes:
        c = cell(s, f)
        t = c["trmse"]
        row.append(f"{c['mean_ssim']:.3f} / {t:.4f}" if t is not None else f"{c['mean_ssim']:.3f} / -")
    m = summary[f]
    t = m["mean_trmse"]
    print(f"| {f} | " + " | ".join(row) + f" | **{m['mean_ssim']:.3f} / {t:.4f}** |")
