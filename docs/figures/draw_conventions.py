"""Draw the convention figures of docs/conventions.md from the workbench's own code.

    .venv/bin/python docs/figures/draw_conventions.py            # rewrites the PNGs beside this file
    .venv/bin/python docs/figures/draw_conventions.py --out DIR  # somewhere else

The linkage is drawn with ``workbench.hydro.kinematics.leg_state`` and the robot with
``workbench.hydro.robot.RobotSettings``, so the pictures cannot drift from the code. Output is
byte-for-byte reproducible (fixed pose, Agg backend, no timestamp in the PNG metadata).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Arc, FancyArrowPatch  # noqa: E402

from workbench.hydro.kinematics import DEFAULT_GEOMETRY, leg_state  # noqa: E402
from workbench.hydro.robot import LEG_NAMES, RobotSettings  # noqa: E402

HERE = Path(__file__).resolve().parent
#: the pose drawn (deg): a mid-stroke leg
THETA_H, THETA_K = -55.0, 25.0


def _arrow(ax, start, end, colour, label=None, lw=1.8, text_offset=(0.0, 0.0), **kw):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=12, color=colour, lw=lw, **kw))
    if label:
        ax.text(end[0] + text_offset[0], end[1] + text_offset[1], label, color=colour, fontsize=9)


def _angle_arc(ax, centre, radius, start_deg, end_deg, colour, label, label_radius=None):
    lo, hi = sorted((start_deg, end_deg))
    ax.add_patch(Arc(centre, 2 * radius, 2 * radius, theta1=lo, theta2=hi, color=colour, lw=1.2))
    mid = math.radians((start_deg + end_deg) / 2)
    rr = label_radius or radius * 1.25
    ax.text(centre[0] + rr * math.cos(mid), centre[1] + rr * math.sin(mid), label, color=colour, fontsize=9,
            ha="center", va="center")
    tip = math.radians(end_deg)
    d = 1 if end_deg > start_deg else -1
    ax.annotate("", xy=(centre[0] + radius * math.cos(tip), centre[1] + radius * math.sin(tip)),
                xytext=(centre[0] + radius * math.cos(tip - d * 0.12), centre[1] + radius * math.sin(tip - d * 0.12)),
                arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.0})


def draw_leg(path: Path) -> None:
    """The leg plane: linkage, joint angles, web and its normal, flow, load-cell axes."""
    st = leg_state(math.radians(THETA_H), math.radians(THETA_K))
    o = np.zeros(2)
    a, b, c, q, n, t = (np.asarray(v) for v in (st.a, st.b, st.c, st.q, st.normal, st.tangent))
    fig, ax = plt.subplots(figsize=(8.0, 6.4), dpi=110)
    # links
    for p0, p1, style, lab, off in ((o, c, "-", "thigh OC = 0.125", (-0.075, -0.01)),
                                    (o, a, "-", "crank OA\n= 0.035", (-0.045, 0.0)),
                                    (a, b, "--", "coupler AB = 0.125", (0.008, 0.0)),
                                    (b, q, "-", "calf: BQ = 2.5 BC", (0.012, -0.012))):
        ax.plot([p0[0], p1[0]], [p0[1], p1[1]], style, color="0.25", lw=2.2 if style == "-" else 1.4)
        m = (p0 + p1) / 2
        ax.text(m[0] + off[0], m[1] + off[1], lab, fontsize=7.5, color="0.35")
    # web: a plate along the calf, centred on Q
    half = DEFAULT_GEOMETRY.web_side_m / 2
    w0, w1 = q - half * t, q + half * t
    ax.plot([w0[0], w1[0]], [w0[1], w1[1]], color="tab:cyan", lw=7, solid_capstyle="butt", alpha=0.8)
    ax.text(w0[0] - 0.105, w0[1] + 0.004, "web 0.06 x 0.06 m, midplane\n0.02 m off the leg plane (+x)",
            fontsize=7.5, color="tab:cyan")
    for name, p, off in (("O (hip axis)", o, (-0.045, 0.008)), ("A", a, (-0.012, 0.004)), ("B", b, (0.004, 0.004)),
                         ("C", c, (0.006, -0.002)), ("Q", q, (-0.016, -0.006))):
        ax.plot(*p, "o", color="k", ms=4)
        ax.text(p[0] + off[0], p[1] + off[1], name, fontsize=9, weight="bold")
    # web normal and tangent at Q
    _arrow(ax, q, q + 0.045 * n, "tab:red", "n (web normal)", text_offset=(0.003, -0.004))
    _arrow(ax, q, q + 0.04 * t, "tab:purple", "t (calf)", text_offset=(0.004, -0.006), lw=1.2)
    # joint angles
    _angle_arc(ax, o, 0.03, 0.0, THETA_H, "tab:blue", r"$\theta_h$")
    ax.plot([0, 0.05], [0, 0], ":", color="tab:blue", lw=1)
    perp = THETA_H + 90.0
    ax.plot([0, 0.05 * math.cos(math.radians(perp))], [0, 0.05 * math.sin(math.radians(perp))], ":",
            color="tab:green", lw=1)
    _angle_arc(ax, o, 0.022, perp, perp + THETA_K, "tab:green", r"$\theta_k$", label_radius=0.034)
    ax.text(-0.14, -0.205, r"$\psi$ (crank OA) $= \theta_h + \theta_k + 90°$; B = A + C (parallelogram)"
            "\nQ = B + 2.5 (C - B); n = calf direction turned +90°", fontsize=8, color="0.2")
    # frames: leg plane (X, Y) = load cell (y, z); load-cell x out of the page
    base = np.array([-0.13, -0.085])
    _arrow(ax, base, base + [0.045, 0], "k", "X = load cell +y\n(forward, swim)", text_offset=(0.004, -0.004))
    _arrow(ax, base, base + [0, 0.045], "k", "Y = load cell +z (up)", text_offset=(-0.01, 0.005))
    ax.plot(*base, "o", mfc="white", mec="k", ms=9)
    ax.plot(*base, "o", color="k", ms=2.5)
    ax.text(base[0] - 0.012, base[1] - 0.022, "load cell +x\n(hip axis, out of page)", fontsize=7.5)
    # flow
    for yy in (-0.17, -0.14, -0.11):
        _arrow(ax, np.array([0.19, yy]), np.array([0.135, yy]), "tab:gray", lw=1.2)
    ax.text(0.112, -0.2, "tunnel flow U along\nload cell -y (= robot\nswimming +y at U)", fontsize=8,
            color="tab:gray")
    ax.set_aspect("equal")
    ax.set_xlim(-0.15, 0.2)
    ax.set_ylim(-0.215, 0.06)
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(f"Leg plane, drawn by leg_state at theta_h = {THETA_H:g} deg, theta_k = {THETA_K:g} deg",
                 fontsize=10)
    ax.grid(alpha=0.25)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def draw_robot(path: Path) -> None:
    """Top view (body frame, legs, world frame, yaw) and front view (HAA abduction, mirrored legs)."""
    robot = RobotSettings()
    haa = np.asarray(robot.haa_position_m)
    hips = robot.hip_positions_m()
    rot, _ = robot.leg_rotations()
    fig, (top, front) = plt.subplots(1, 2, figsize=(10.5, 5.4), dpi=110, gridspec_kw={"width_ratios": [1.1, 1]})
    # top view: body outline, legs, frames
    length, width = robot.body_length_m, 0.14
    top.add_patch(plt.Rectangle((-width / 2, -length / 2), width, length, fc="0.92", ec="0.4"))
    _arrow(top, (0, 0), (0.06, 0), "k", "+x right", text_offset=(0.004, -0.004))
    _arrow(top, (0, 0), (0, 0.06), "k", "+y forward", text_offset=(-0.022, 0.008))
    top.plot(0, 0, "ko", ms=4)
    top.text(0.006, -0.018, "metacenter", fontsize=8)
    for i, name in enumerate(LEG_NAMES):
        top.plot(haa[i, 0], haa[i, 1], "s", color="tab:blue", ms=6)
        top.plot([haa[i, 0], hips[i, 0]], [haa[i, 1], hips[i, 1]], color="tab:blue", lw=1)
        top.plot(hips[i, 0], hips[i, 1], "o", color="tab:orange", ms=5)
        lc_x = rot[i] @ np.array([1.0, 0, 0])
        start = hips[i, :2] + [0.0, -0.025]
        _arrow(top, start, start + 0.05 * lc_x[:2], "tab:orange", lw=1.2)
        mirrored = " (mirrored)" if robot.mirrored[i] else ""
        top.text(hips[i, 0] + (0.012 if hips[i, 0] > 0 else -0.1), hips[i, 1] + 0.015,
                 f"{name}{mirrored}\nHAA {robot.haa_angle_deg[i]:g} deg", fontsize=8)
    top.text(-0.2, -0.245, "squares: HAA joints (axis along body +y); dots: load-cell origins;\n"
             "orange arrows: each leg's load-cell +x (a right leg's frame is the mirror image)", fontsize=7.5)
    _angle_arc(top, (0, -0.02), 0.045, 90, 160, "tab:red", "yaw > 0\n(left turn)", label_radius=0.07)
    top.set_aspect("equal")
    top.set_xlim(-0.22, 0.22)
    top.set_ylim(-0.26, 0.24)
    top.set_title("Top view: body frame (z up, out of page), yaw counter-clockwise", fontsize=9.5)
    top.grid(alpha=0.25)
    # front view (looking backward from ahead of the robot would flip x; we look from behind: +x right)
    front.add_patch(plt.Rectangle((-width / 2, -0.02), width, 0.05, fc="0.92", ec="0.4"))
    for i in (0, 1):  # front legs: abducted by the HAA angle
        down = rot[i] @ np.array([0.0, 0.0, -0.16])
        front.plot([hips[i, 0], hips[i, 0] + down[0]], [hips[i, 2], hips[i, 2] + down[2]], color="tab:blue", lw=3)
        front.plot([hips[i, 0], hips[i, 0]], [0, -0.16], ":", color="0.5")
        front.text(hips[i, 0] + down[0] + (-0.06 if i == 0 else 0.0), down[2] - 0.035,
                   f"{LEG_NAMES[i]}: {robot.haa_angle_deg[i]:g} deg\noutboard", fontsize=8)
        _arrow(front, hips[i, [0, 2]], hips[i, [0, 2]] + 0.05 * (rot[i] @ np.array([1.0, 0, 0]))[[0, 2]],
               "tab:orange", lw=1.2)
    _arrow(front, (0.0, 0.05), (0.06, 0.05), "k", "+x (right)", text_offset=(0.005, -0.005))
    _arrow(front, (0.0, 0.05), (0.0, 0.11), "k", "+z (up)", text_offset=(0.005, 0.0))
    front.text(-0.17, -0.23, "Seen from behind (+y into the page). A positive HAA angle abducts:\n"
               "the leg swings outboard and up on both sides (paper: front legs 30 deg).\n"
               "Right legs: F -> (-fx, fy, fz), tau -> (tx, -ty, -tz) (mirror, torques axial).", fontsize=7.5)
    front.set_aspect("equal")
    front.set_xlim(-0.23, 0.23)
    front.set_ylim(-0.25, 0.13)
    front.set_title("Front legs seen from behind: HAA abduction", fontsize=9.5)
    front.grid(alpha=0.25)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    """Write leg_conventions.png and robot_frames.png."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE, help="output folder (default: docs/figures)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    draw_leg(args.out / "leg_conventions.png")
    draw_robot(args.out / "robot_frames.png")


if __name__ == "__main__":
    main()
