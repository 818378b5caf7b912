"""The seed paper's Fig. 1: a U-shaped layer, its motion restriction P and as-built S.

A U (10 × 8 mm, a notch 2 mm wide down to a 2 mm base) is printed with:

* a 1 mm round nozzle on XY: only the six convex corners are lost, exactly
  6·(1 − π/4)·r²;
* a 2.5 mm round nozzle: it fits both 4 mm arms but not the 2 mm base, so P
  splits into two components (the seed's disconnected P₁, P₂): two extruders
  on one head could print the arms at once;
* an elliptical nozzle 2.4 × 0.8 mm, turned across the arms, on XY and on a
  T-T-R machine: turning it lets it reach what the fixed orientation cannot.

Then the nozzles are ranked (least lost first, ties by build time). Run::

    python examples/u_shape.py [--plot u_shape.png]
"""

from __future__ import annotations

import argparse
import math

from shapely.geometry import box

from printability.analysis.ranking import rank
from printability.mmc import compute_mmc
from printability.settings import Settings


def u_shape(width=10.0, height=8.0, gap=2.0, base=2.0):
    """Outer width × height; a notch ``gap`` wide from the top down to ``base``."""
    notch = box((width - gap) / 2, base, (width + gap) / 2, height + 1.0)
    return box(0.0, 0.0, width, height).difference(notch)


CASES = [
    ("circle:d=1", "xy"),
    ("circle:d=2.5", "xy"),
    ("ellipse:major=2.4,minor=0.8", "xy"),
    ("ellipse:major=2.4,minor=0.8", "ttr"),
]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="The seed paper's Fig. 1 U-shape.")
    ap.add_argument("--plot", metavar="PNG", help="draw G, S and P (needs matplotlib)")
    args = ap.parse_args(argv)
    g = u_shape()
    settings = Settings(angle_step=5.0)
    print(f"U-shape: area {g.area:.3f} mm²")
    results = []
    for spec, machine in CASES:
        res = compute_mmc(g, spec, machine, engine="exact", settings=settings)
        results.append(res)
        lo, hi = res.lost_area_bounds
        print(f"  {spec:<30} {machine:<4} lost {res.lost_area:7.4f} mm² "
              f"[{lo:.4f}, {hi:.4f}]  ({100 * res.lost_fraction:5.2f} %), "
              f"P: {res.components.count} component(s), {len(res.motion.angles)} angle(s)")
    print(f"  closed form for d=1: 6·(1 − π/4)·0.25 = {6 * (1 - math.pi / 4) * 0.25:.4f} mm²")
    print("ranking (least lost, then fastest):")
    for row in rank(results):
        print(f"  {row.rank}. {row.spec} on {row.machine}: lost {row.lost:.4f} {row.unit}, "
              f"est. build {row.build_time:.2f} s (bead {row.bead_width:.2f} mm)")
    if args.plot:
        _plot(g, results, args.plot)
        print(f"figure written to {args.plot}")
    return 0


def _plot(g, results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from shapely.plotting import plot_polygon

    fig, axes = plt.subplots(1, len(results), figsize=(4 * len(results), 4))
    for ax, res in zip(axes, results, strict=True):
        plot_polygon(g, ax=ax, add_points=False, facecolor="#eeeeee", edgecolor="black")
        if not res.as_built.is_empty:
            plot_polygon(res.as_built, ax=ax, add_points=False, facecolor="#8ecae6",
                         edgecolor="none")
        for geom in res.components.geometries or ():
            plot_polygon(geom, ax=ax, add_points=False, facecolor="#fb8500", edgecolor="none",
                         alpha=0.8)
        ax.set_title(f"{res.nozzle.spec}\n{res.machine.name}: lost {res.lost_area:.3f} mm²",
                     fontsize=9)
        ax.set_aspect("equal")
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    raise SystemExit(main())
