"""The conventions figure of the concepts page (docs/concepts.md), drawn at every docs build by
docs/_ext/hooks.py from the package's own geometry (``Chain.positions``, ``Chain.com_positions``),
so the picture cannot disagree with the model. Run it alone to write the SVG somewhere:

    .venv/bin/python docs/_ext/conventions_figure.py out/conventions.svg
"""
from __future__ import annotations

import io
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Arc, FancyArrowPatch, Rectangle  # noqa: E402

import multipendulum as mp  # noqa: E402

INK, GREY, BLUE, RED, GREEN = "#222222", "#9a9a9a", "#1f5fa8", "#b8332b", "#2c7a3f"


def _arrow(ax, start, end, color=INK, **kw):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=12, color=color,
                                 linewidth=1.3, shrinkA=0, shrinkB=0, **kw))


def _angle(ax, centre, theta, radius, label, color):
    """The arc from the downward vertical at ``centre`` to the angle ``theta`` (CCW positive)."""
    start = -90.0  # degrees: straight down
    ax.plot([centre[0], centre[0]], [centre[1], centre[1] - 1.25 * radius], ls=(0, (4, 3)), color=GREY, lw=1)
    ax.add_patch(Arc(centre, 2 * radius, 2 * radius, theta1=start, theta2=start + np.degrees(theta),
                     color=color, lw=1.4))
    tip = np.radians(start + np.degrees(theta))
    head = centre + radius * np.array([np.cos(tip), np.sin(tip)])
    back = centre + radius * np.array([np.cos(tip - 0.12), np.sin(tip - 0.12)])
    _arrow(ax, back, head, color=color)
    mid = np.radians(start + np.degrees(theta) / 2)
    ax.text(*(centre + 1.35 * radius * np.array([np.cos(mid), np.sin(mid)])), label, color=color,
            ha="center", va="center", fontsize=12)


def _chain_panel(ax):
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7], com=[0.55, 0.45], inertia=[0.05, 0.03])
    theta = np.array([0.55, 1.25])
    joints = np.vstack([[0.0, 0.0], chain.positions(theta)])
    coms = chain.com_positions(theta)
    ax.axhline(0, color=GREY, lw=0.6)
    ax.axvline(0, color=GREY, lw=0.6)
    _arrow(ax, (-1.05, -1.35), (-0.55, -1.35))
    ax.text(-0.5, -1.35, "x", va="center", fontsize=11)
    _arrow(ax, (-1.05, -1.35), (-1.05, -0.85))
    ax.text(-1.05, -0.78, "y", ha="center", fontsize=11)
    _arrow(ax, (1.55, 0.25), (1.55, -0.35), color=GREEN)
    ax.text(1.62, -0.05, "g", color=GREEN, fontsize=12, va="center")
    for i in range(2):
        ax.plot(*joints[i:i + 2].T, color=INK, lw=5, solid_capstyle="round")
        ax.plot(*coms[i], "o", ms=9, mfc="white", mec=INK, mew=1.6)
        ax.plot(*coms[i], "o", ms=3, color=INK)
        d = joints[i + 1] - joints[i]
        normal = np.array([d[1], -d[0]]) / np.linalg.norm(d)
        ax.text(*(0.5 * (joints[i] + joints[i + 1]) - 0.16 * normal), f"$l_{i + 1}$", fontsize=12,
                ha="center", va="center")
        ax.text(*(coms[i] + (0.36 if i == 0 else 0.3) * normal), f"$m_{i + 1}$, $I_{i + 1}$ about the\n"
                f"centre of mass, $c_{i + 1}$\nfrom joint {i + 1}", fontsize=8.5, ha="center", va="center")
        _angle(ax, joints[i], theta[i], 0.3 if i == 0 else 0.2, fr"$\theta_{i + 1}$", BLUE)
    for i, name in enumerate(["joint 1: base to link 1", "joint 2: link 1 to link 2"]):
        ax.plot(*joints[i], "o", ms=7, color=RED, zorder=5)
        ax.text(joints[i][0] + (0.08 if i == 0 else -0.08), joints[i][1] + (0.1 if i == 0 else -0.08), name,
                color=RED, fontsize=9, ha="left" if i == 0 else "right", va="bottom" if i == 0 else "top")
    ax.text(*(joints[2] + [0.05, -0.12]), "tip", fontsize=9)
    ax.text(-1.15, 0.32, "joint i turns at $w_i = \\omega_i - \\omega_{i-1}$ ($\\omega_0 = 0$); its torque\n"
            "$u_i$ ($-b_i w_i$, $-f_i \\tanh(w_i / v_s)$, a motor) acts $+u_i$ on link i, $-u_i$ on link i-1",
            fontsize=8.5, va="bottom")
    ax.set_title("angles absolute from the downward vertical, CCW positive", fontsize=10)
    ax.set_xlim(-1.2, 2.0)
    ax.set_ylim(-1.55, 0.62)


def _cart_panel(ax):
    chain = mp.Chain.rods([0.9], [0.5], cart=mp.Cart(1.0, damping=0.1))
    theta = np.array([np.pi - 0.45])
    x = 0.35
    tip = chain.positions(theta)[0] + [x, 0.0]
    ax.plot([-0.9, 1.5], [-0.13, -0.13], color=GREY, lw=2)
    ax.add_patch(Rectangle((x - 0.3, -0.1), 0.6, 0.2, fc="#e8e8e8", ec=INK, lw=1.2))
    ax.plot([x, tip[0]], [0, tip[1]], color=INK, lw=5, solid_capstyle="round")
    ax.plot(x, 0, "o", ms=7, color=RED, zorder=5)
    _angle(ax, np.array([x, 0.0]), theta[0], 0.26, r"$\theta_1$", BLUE)
    _arrow(ax, (x - 0.85, -0.05), (x - 0.32, -0.05), color=GREEN)
    ax.text(x - 0.85, 0.03, "F (cart_force)", color=GREEN, fontsize=9)
    ax.plot([0, 0], [-0.25, -0.35], color=INK, lw=1)
    _arrow(ax, (0, -0.3), (x, -0.3))
    ax.text(x / 2, -0.4, "x", ha="center", va="top", fontsize=12)
    ax.text(-0.85, 0.95, "state (x, θ₁..θ_N, v, ω₁..ω_N),\nthe cart first; upright: θ = π", fontsize=9)
    ax.set_title("on a cart (mp.Cart)", fontsize=10)
    ax.set_xlim(-0.95, 1.55)
    ax.set_ylim(-0.6, 1.15)


def draw() -> str:
    """The figure as SVG text (deterministic: no date, fixed ids)."""
    with plt.rc_context({"svg.hashsalt": "multipendulum", "svg.fonttype": "path", "font.size": 10}):
        fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.4), gridspec_kw={"width_ratios": [3.2, 2.5]})
        _chain_panel(axes[0])
        _cart_panel(axes[1])
        for ax in axes:
            ax.set_aspect("equal")
            ax.axis("off")
        fig.tight_layout()
        out = io.StringIO()
        fig.savefig(out, format="svg", metadata={"Date": None})
        plt.close(fig)
    return out.getvalue()


if __name__ == "__main__":
    target = sys.argv[1] if len(sys.argv) > 1 else "conventions.svg"
    with open(target, "w", encoding="utf-8") as f:
        f.write(draw())
    print(f"wrote {target}")
