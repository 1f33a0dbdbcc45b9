"""Figs. 5-7 of the paper redrawn from the runs of :mod:`benchmarks.paper` (matplotlib, the
[dev] extra; PNGs under ``docs/img/``).
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.paper import (
    LOST_INDEX,
    PAPER_CONFIGS,
    PAPER_GAMMA,
    PaperRun,
    until,
)
from glmav_observer.configurations import LOST_AXIS_OF_CONFIG

_FORM_STYLE = {
    "exact": {"color": "tab:blue", "ls": "-", "label": "estimate, exact E (13)"},
    "small_angle": {"color": "tab:red", "ls": "--", "label": "estimate, small-angle E (15)"},
}


def plot_fig5(runs: dict[str, PaperRun], path: Path) -> None:
    """Fig. 5 equivalent: body velocity estimates vs truth, 1 s, all three configurations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 3, figsize=(12, 8), sharex=True)
    names = ("u", "v", "w")
    ref = runs["exact"]
    sel = until(ref, 1.0)
    for j, c in enumerate(PAPER_CONFIGS):
        for i in range(3):
            ax = axes[i, j]
            ax.plot(
                ref.t_s[sel], ref.v_body_true_mps[sel, i], "k", lw=1.5, label="truth (SIM_STATE)"
            )
            for form, run in runs.items():
                s = until(run, 1.0)
                ax.plot(run.t_s[s], run.v_body_hat_mps[c][s, i], **_FORM_STYLE[form], lw=1.2)
            ax.set_ylabel(f"{c}: {names[i]} (m/s)")
            ax.grid(alpha=0.3)
        axes[0, j].set_title(f"{c} (γ = {PAPER_GAMMA[c]:g}, {LOST_AXIS_OF_CONFIG[c]} lost)")
        axes[2, j].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Fig. 5 equivalent: body velocity, truth vs estimates (x̂0 = 0, eq. 49)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_fig6(runs: dict[str, PaperRun], path: Path, *, frame: str, t_end: float) -> None:
    """Fig. 6 equivalent: errors x − x̂ (the paper's sign) in body axes (u, v, w) or the
    earth-frame error in NED (n, e, d), all three configurations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 3, figsize=(12, 8), sharex=True)
    names = ("u", "v", "w") if frame == "body" else ("n", "e", "d")
    for j, c in enumerate(PAPER_CONFIGS):
        for form, run in runs.items():
            s = until(run, t_end)
            err = -(run.err_body(c) if frame == "body" else run.err_ned(c))
            for i in range(3):
                axes[i, j].plot(run.t_s[s], err[s, i], **_FORM_STYLE[form], lw=1.2)
        for i in range(3):
            ax = axes[i, j]
            ax.axhline(0.0, color="k", lw=0.6)
            lost = frame == "ned" and i == LOST_INDEX[c]
            ax.set_ylabel(f"{c}: e_{names[i]} (m/s)" + ("  [lost]" if lost else ""))
            if lost:
                ax.set_facecolor("#f4f0e6")
            ax.grid(alpha=0.3)
        axes[0, j].set_title(f"{c} (γ = {PAPER_GAMMA[c]:g}, {LOST_AXIS_OF_CONFIG[c]} lost)")
        axes[2, j].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8)
    what = "body axes (the paper's Fig. 6)" if frame == "body" else "earth axes NED"
    fig.suptitle(f"Fig. 6 equivalent: error x − x̂ in {what}, {t_end:g} s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_fig7(clean: PaperRun, noisy: PaperRun, sigma: float, path: Path) -> None:
    """Fig. 7 equivalent: (a) Γ with and without noise, (b) Δû = û_noisy − û per config."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    s = until(clean, 1.0)
    for i, col in enumerate(("tab:blue", "tab:orange", "tab:green")):
        a.plot(noisy.t_s[s], noisy.gamma_in_mps2[s, i], color=col, lw=0.3, alpha=0.5)
    for i, col in enumerate(("tab:blue", "tab:orange", "tab:green")):
        a.plot(clean.t_s[s], clean.gamma_in_mps2[s, i], color=col, lw=1.8, label=f"Γ{i + 1}")
    a.set_ylabel("Γ (m/s²)")
    a.set_title(
        f"(a) Γ = f + g_body, clean (thick) and with white noise σ = {sigma:.2f} m/s² (thin)"
    )
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    for c, col in zip(PAPER_CONFIGS, ("tab:blue", "tab:orange", "tab:green"), strict=True):
        du = noisy.v_body_hat_mps[c][s, 0] - clean.v_body_hat_mps[c][s, 0]
        b.plot(clean.t_s[s], du, color=col, lw=0.8, label=f"{c}: Δû")
    b.axhspan(-1e-3, 1e-3, color="grey", alpha=0.3, label="paper: ~1e-3 m/s")
    b.set_ylabel("Δû = û_noisy − û (m/s)")
    b.set_xlabel("t (s)")
    b.set_title("(b) effect of the noise on û (exact E)")
    b.legend(fontsize=8)
    b.grid(alpha=0.3)
    fig.suptitle("Fig. 7 equivalent")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
