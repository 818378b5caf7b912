"""One part on four machines: XY, T-T-R, a polar printer and a SCARA arm.

The seed paper's U-shape (10 × 8 mm, a 2 mm notch) sits on the bed at x = 30…40 mm,
y = 0…8 mm. Two nozzles print it: a 0.4 mm round one and an elliptical 0.8 × 0.3 mm
one. On XY the ellipse keeps its orientation; on T-T-R a rotary axis turns it freely;
on the polar printer (the bed turns under a radial arm) it turns with the bed, so its
major axis always points at the bed's centre; on the SCARA arm (shoulder, elbow, no
wrist) it turns with the arm. The chains are not separable: the sampled engine samples
their joints (``printability/data/machines/polar.toml`` and ``scara.toml`` set the
steps) and tests the nozzle's containment at every sample.

For every case the table gives the lost area with its bounds, the components of the
motion restriction P (on the SCARA arm: elbow left and elbow right) and the time.
Run::

    python examples/chains.py [--fine] [--plot chains.png]

``--fine`` halves the SCARA steps (0.05°), which gives a lower bound for the 0.4 mm
nozzle too (about 4× slower). The whole run takes about a minute.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import shapely.affinity
from shapely.geometry import box

from printability.mmc import compute_mmc
from printability.model.machine import parse_machine
from printability.settings import Settings

NOZZLES = ("circle:d=0.4", "ellipse:major=0.8,minor=0.3")


def u_shape(width=10.0, height=8.0, gap=2.0, base=2.0):
    """The seed's Fig. 1 U: outer width × height, a notch ``gap`` wide down to ``base``."""
    notch = box((width - gap) / 2, base, (width + gap) / 2, height + 1.0)
    return box(0.0, 0.0, width, height).difference(notch)


def machines(fine: bool):
    scara = parse_machine("scara")
    if fine:
        scara = replace(scara, joints=tuple(replace(j, step=0.05) for j in scara.joints))
    return [("xy", "xy", "exact"), ("ttr", "ttr", "exact"),
            ("polar", parse_machine("polar"), "sampled"), ("scara", scara, "sampled")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="A part on XY, T-T-R, polar and SCARA machines.")
    ap.add_argument("--fine", action="store_true", help="SCARA steps of 0.05° (slower)")
    ap.add_argument("--plot", metavar="PNG", help="draw G and S per machine (matplotlib)")
    args = ap.parse_args(argv)
    g = shapely.affinity.translate(u_shape(), 30.0, 0.0)
    settings = Settings(angle_step=5.0)
    print(f"U-shape at x = 30…40 mm, y = 0…8 mm: area {g.area:.3f} mm²")
    print(f"  {'machine':<7} {'nozzle':<28} {'engine':<8} {'lost mm²':>9}  "
          f"{'bounds':<19} {'P comps':>7} {'samples':>10} {'time':>6}")
    results = {}
    for label, machine, engine in machines(args.fine):
        for spec in NOZZLES:
            t0 = time.perf_counter()
            res = compute_mmc(g, spec, machine, engine=engine, settings=settings)
            results[(label, spec)] = res
            lo, hi = res.lost_area_bounds
            n = f"{res.extra['samples']:,}" if engine == "sampled" else "-"
            print(f"  {label:<7} {spec:<28} {engine:<8} {res.lost_area:9.4f}  "
                  f"[{lo:7.4f}, {hi:7.4f}] {res.components.count:7d} {n:>10} "
                  f"{time.perf_counter() - t0:5.1f}s")
            for note in res.notes[1:]:
                print(f"      note: {note}")
    print("The polar and SCARA bounds are wider: a configuration between two samples can move "
          "the nozzle by the slack L of the notes, while the separable engines are exact.")
    if args.plot:
        _plot(g, results, args.plot)
    return 0


def _plot(g, results, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from printability.model.geometry import polygons_of

    labels = sorted({k[0] for k in results}, key=["xy", "ttr", "polar", "scara"].index)
    fig, axes = plt.subplots(len(NOZZLES), len(labels), figsize=(3.2 * len(labels), 6.4))
    for i, spec in enumerate(NOZZLES):
        for j, label in enumerate(labels):
            ax = axes[i][j]
            res = results[(label, spec)]
            for p in polygons_of(g):
                ax.fill(*p.exterior.xy, color="#dddddd")
            for p in polygons_of(res.as_built):
                ax.fill(*p.exterior.xy, color="#4c72b0")
                for hole in p.interiors:
                    ax.fill(*hole.xy, color="#dddddd")
            ax.set_title(f"{label}\n{spec}\nlost {res.lost_area:.3f} mm²", fontsize=8)
            ax.set_aspect("equal")
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    print(f"figure written to {path}")


if __name__ == "__main__":
    raise SystemExit(main())
