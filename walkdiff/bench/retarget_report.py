"""The one-screen summary of `walkdiff bench retarget` and the tally of its figures' targets."""

from __future__ import annotations

import numpy as np


def checks(result: dict) -> dict:
    """How many figures with a target passed, and which did not (section / case / figure)."""
    found = []

    def walk(node, path):
        if isinstance(node, dict) and "pass" in node:
            found.append((" / ".join(path), node["pass"]))
        elif isinstance(node, dict):
            for key, value in node.items():
                walk(value, [*path, key])

    for section in ("same_proportions", "other_proportions", "real_pairs", "circling", "speed"):
        walk(result.get(section, {}), [section])
    return {
        "checked": len(found),
        "passed": sum(ok for _, ok in found),
        "failed": [p for p, ok in found if not ok],
    }


def _show(figure, spec: str = "{:.2f}") -> str:
    """A figure as text; '!' after one that misses its target."""
    value = figure["value"] if isinstance(figure, dict) else figure
    if isinstance(value, bool):
        text = "yes" if value else "NO"
    else:
        text = "n/a" if value is None or not np.isfinite(value) else spec.format(value)
    return text + ("!" if isinstance(figure, dict) and not figure["pass"] else "")


def _pair_row(name: str, f: dict) -> str:
    def two(a: str, b: str, spec: str = "{:.2f}", join: str = "/") -> str:
        return _show(f[a], spec) + join + _show(f[b], spec)

    turn = _show(f["hands_feet_turn_max_deg"], "{:.1f}") if "hands_feet_turn_max_deg" in f else "-"
    return (
        f"  {name:24s} {two('bones_median_deg', 'bones_p95_deg'):>10s} "
        f"{two('bones_worst_median_deg', 'bones_worst_p95_deg'):>11s} "
        f"{two('legs_free_median_deg', 'legs_free_p95_deg'):>10s} "
        f"{_show(f['legs_with_ik_worst_median_deg']):>6s} {turn:>5s} "
        f"{_show(f['path_length_error'], '{:.1e}'):>7s} "
        f"{two('skate_ratio', 'skate_ratio_source', '{:.3f}', ' (') + ')':>14s} "
        f"{two('contacts_kept_own', 'contacts_kept_scaled', '{:.3f}'):>16s} "
        f"{_show(f['below_floor'], '{:.4f}'):>7s} {_show(f['sides_kept']):>5s}"
    )


def summary(result: dict) -> list[str]:
    """One screen: every case's main figures, then the checks that failed."""
    zeggs = result["zeggs"]
    lines = [
        f"bench retarget: {len(result['clips'])} Xia clips (<= {max(c['frames'] for c in result['clips'])} "
        f"frames)"
        + (f", ZEGGS {zeggs['take']} ({zeggs['windows']} windows)" if zeggs else ", no ZEGGS")
        + f"; {result['seconds']} s",
        f"{'same proportions (body heights; target 0.005)':58s} {'position max':>13s} {'round trip':>12s}",
    ]
    for name, f in result["same_proportions"].items():
        pos, back = _show(f["position_error_max"], "{:.1e}"), _show(f["round_trip_max"], "{:.1e}")
        lines.append(f"  {name:56s} {pos:>13s} {back:>12s}")
    lines.append(
        f"{'pair (degrees: median/p95)':26s} {'bones':>10s} {'worst bone':>11s} {'legs off':>10s} "
        f"{'leg IK':>6s} {'h+f':>5s} {'path':>7s} "
        f"{'skate (src)':>14s} {'contacts own/sc':>16s} {'below':>7s} {'sides':>5s}"
    )
    for name, f in [*result["other_proportions"].items(), *result["real_pairs"].items()]:
        if "bones_median_deg" in f:
            lines.append(_pair_row(name, f))
    circling = result.get("circling_clips")
    if circling:
        lines.append(
            f"circling round {circling['radius_m']:g} m: "
            f"{', '.join(circling['clips']) or 'no clip travels'}; {circling['big']}"
        )
    for name, f in result.get("circling", {}).items():
        lines.append(_pair_row(name, f))
    trip = result["real_pairs"].get("xia -> zeggs -> xia")
    if trip:
        lines.append(
            f"xia -> zeggs -> xia: round trip max {trip['round_trip_max']:.4f}, "
            f"mean {trip['round_trip_mean']:.4f} body heights (no target)"
        )
    speed = result["speed"]
    lines.append(
        f"speed ({speed['clip']}, {speed['frames']} frames; load {speed['load_average_1min']}): frames/s "
        "prepared (one-shot, prepared with torch on 1 thread)"
    )
    for name, row in speed.items():
        if isinstance(row, dict):
            lines.append(
                f"  {name:28s} {_show(row['frames_per_s'], '{:,.0f}'):>10s} "
                f"({_show(row['one_shot_frames_per_s'], '{:,.0f}')}, "
                f"{_show(row['frames_per_s_torch_1_thread'], '{:,.0f}')})"
            )
    c = result["checks"]
    lines.append(f"checks: {c['passed']} of {c['checked']} reach their targets ('!' marks those that do not)")
    lines += [f"  missed: {path}" for path in c["failed"]]
    return lines
