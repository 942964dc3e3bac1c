"""`skyherd study shepherd`'s figure: the fraction of episodes at the goal against time per
selector, and one seed's shepherd and flock-centre tracks. matplotlib is imported inside."""

from __future__ import annotations

from pathlib import Path


def plot_shepherd(eps, task, flock, path: Path, seed: int, sels) -> None:
    """Left: the fraction of episodes with the flock at the goal against time, per selector;
    right: seed `seed`'s shepherd and flock-centre tracks with the goal region."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from skyherd.policy.shepherd.episode import run_episode

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.6))
    t = np.linspace(0, task.limit_s, 401)
    for name, es in eps.items():
        times = np.array([e.time_to_goal_s if e.success else np.inf for e in es])
        a.plot(t, [(times <= x).mean() for x in t], label=name)
    a.set_xlabel("time [s]")
    a.set_ylabel("fraction of episodes with the flock at the goal")
    a.grid(alpha=0.3)
    a.legend()
    for name, sel in sels.items():
        ep = run_episode(seed, sel, flock, task, keep_track=True)
        tr = np.array(ep.track)
        b.plot(tr[:, 2], tr[:, 1], lw=0.8, label=f"{name}: shepherd")
        b.plot(tr[:, 4], tr[:, 3], lw=1.6, label=f"{name}: flock centre")
    b.add_patch(plt.Circle(task.goal_ne[::-1], task.goal_radius_m, color="g", alpha=0.2,
                           label="goal"))  # fmt: skip
    b.set_xlabel("east [m]")
    b.set_ylabel("north [m]")
    b.set_aspect("equal")
    b.set_title(f"seed {seed}")
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
