"""
The study's figures as PNG files (matplotlib, Agg backend, no display needed).

- :func:`heat_maps`: generality heat maps, one per subject and their average (the paper's
  generality figure), rows = pair learnt on, columns = pair executed on, colour = score.
- :func:`task_time_bars`: full-throw time of demonstrations and LfD executions per pair,
  grouped by phantom (the paper's task-time figure).
- :func:`trajectory_figure`: a demonstrated and a regenerated needle trajectory of subtasks ii
  and iv, positions in 3-D (mm) and orientation quaternions against normalised time (the paper's
  Fig. 7).
"""

from collections.abc import Mapping
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

_CMAP = 'RdYlGn'


def _annotate(ax: Any, m: np.ndarray) -> None:
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            if not math.isnan(m[i, j]):
                ax.text(j, i, f'{m[i, j]:.2f}'.rstrip('0').rstrip('.') if m[i, j] % 1 else
                        f'{m[i, j]:.0f}', ha='center', va='center', fontsize=6)


def heat_maps(gen: Mapping[str, Any], path: str | Path, title: str = '') -> None:
    """
    Draw the per-subject and average generality heat maps into one PNG.

    Parameters
    ----------
    gen : dict
        Output of :func:`suture_lfd.study.tables.generality`.
    path : str or Path
        PNG file to write.
    title : str
        Figure title.

    """
    pairs = gen['pairs']
    subjects = list(gen['matrix'])
    panels = [(f'{s} ({gen["subjects"][s][:3]}) {gen["subject_mean"][s]:.3f}',
               gen['matrix'][s]) for s in subjects]
    panels.append((f'average {gen["group_mean"]["overall"]:.3f}', gen['mean_matrix']))
    cols = min(4, len(panels))
    rows = math.ceil(len(panels) / cols)
    size = 1.0 + 0.32 * len(pairs)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * size + 1.0, rows * size + 0.6),
                             squeeze=False)
    image = None
    for ax, (name, m) in zip(axes.flat, panels):
        image = ax.imshow(m, vmin=0.0, vmax=1.0, cmap=_CMAP)
        ax.set_title(name, fontsize=8)
        ax.set_xticks(range(len(pairs)), pairs, rotation=90, fontsize=6)
        ax.set_yticks(range(len(pairs)), pairs, fontsize=6)
        if len(pairs) <= 8:
            _annotate(ax, m)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis('off')
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.6, label='score (rows: learnt on, cols: run on)')
    if title:
        fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def task_time_bars(times: Mapping[str, Any], path: str | Path, title: str = '') -> None:
    """
    Draw mean full-throw times (with standard deviations) of demonstrations and LfD executions.

    Parameters
    ----------
    times : dict
        Output of :func:`suture_lfd.study.tables.task_times`.
    path : str or Path
        PNG file to write.
    title : str
        Figure title.

    """
    phantoms = list(times)
    fig, axes = plt.subplots(1, max(1, len(phantoms)), figsize=(4.2 * max(1, len(phantoms)), 3.4),
                             squeeze=False)
    for ax, phantom in zip(axes.flat, phantoms):
        ph = times[phantom]
        x = np.arange(len(ph['pairs']))
        for offset, source, label in ((-0.2, 'demo', 'demonstrations'), (0.2, 'lfd', 'LfD')):
            values = [ph[source].get(p, []) for p in ph['pairs']]
            mean = [np.mean(v) if v else 0.0 for v in values]
            std = [np.std(v) if len(v) > 1 else 0.0 for v in values]
            ax.bar(x + offset, mean, 0.4, yerr=std, capsize=2, label=label)
        ax.set_xticks(x, ph['pairs'])
        red = ph['reduction']
        ax.set_title(f'{phantom}: LfD {"-" if red >= 0 else "+"}{abs(red) * 100:.0f} % time'
                     if not math.isnan(red) else phantom, fontsize=9)
        ax.set_ylabel('full throw time (s, simulated)')
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trajectory_figure(curves: Mapping[str, Any], path: str | Path, title: str = '') -> None:
    """
    Draw demonstrated and regenerated needle trajectories (the paper's Fig. 7).

    Parameters
    ----------
    curves : dict
        Task (``'ii'``, ``'iv'``) -> {label: ndarray (n, 7) of needle poses
        ``(x, y, z, qx, qy, qz, qw)`` in ``world``, m}; the first label is drawn as the
        reference (solid), the others dashed.
    path : str or Path
        PNG file to write.
    title : str
        Figure title.

    """
    tasks = list(curves)
    fig = plt.figure(figsize=(9.0, 3.6 * len(tasks)))
    for k, task in enumerate(tasks):
        ax = fig.add_subplot(len(tasks), 2, 2 * k + 1, projection='3d')
        for n, (label, P) in enumerate(curves[task].items()):
            P = np.asarray(P, float)
            ax.plot(*(P[:, :3] * 1e3).T, '-' if n == 0 else '--', label=label, lw=1.2)
        ax.set_title(f'task {task}: needle position (mm)', fontsize=9)
        ax.set_xlabel('x', fontsize=7)
        ax.set_ylabel('y', fontsize=7)
        ax.set_zlabel('z', fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=7)
        ax2 = fig.add_subplot(len(tasks), 2, 2 * k + 2)
        for n, P in enumerate(curves[task].values()):
            Q = np.asarray(P, float)[:, 3:]
            # one sign for the whole curve: the hemisphere of the reference's first sample
            ref = np.asarray(next(iter(curves[task].values())), float)[0, 3:]
            Q = Q * np.where(Q @ ref < 0.0, -1.0, 1.0)[:, None]
            s = np.linspace(0.0, 1.0, len(Q))
            for c, name in enumerate('xyzw'):
                ax2.plot(s, Q[:, c], '-' if n == 0 else '--', color=f'C{c}', lw=1.0,
                         label=f'q{name}' if n == 0 else None)
        ax2.set_title(f'task {task}: needle orientation (solid: {next(iter(curves[task]))})',
                      fontsize=9)
        ax2.set_xlabel('normalised time', fontsize=7)
        ax2.legend(fontsize=7, ncol=4)
        ax2.tick_params(labelsize=6)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
