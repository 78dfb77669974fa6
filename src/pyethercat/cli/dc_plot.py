"""``--plot FILE.png`` of ``pyethercat dc`` and ``pyethercat run --dc`` (matplotlib).

Panels, each where there is data for it:

* the system time difference |0x092C| of every slave that follows the
  reference, over the static drift compensation (the set-up's trace);
* the sync monitor's bound (BRD 0x092C) over the cyclic run;
* the master's phase error against the reference clock (master mode) or the
  reference's distance to the master's time (reference mode);
* the spread of the SYNC0 pulses over time (only with a simulator, which
  knows when each pulse really fired).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pyethercat.errors import ConfigError
from pyethercat.master.dc import DcReport
from pyethercat.master.dc_loop import DcCycle

__all__ = ["Sync0Spread", "check_plot_path", "plot_dc"]


def check_plot_path(path: str) -> None:
    """Refuse a ``--plot`` file that could not be written, before the run starts.

    The figure is drawn after the run; finding then that its directory is
    missing (or matplotlib is) would throw the run's data away.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise ConfigError(f"cannot write the plot {path}: it is a directory")
    if parent.exists() and not parent.is_dir():
        raise ConfigError(f"cannot write the plot {path}: {parent} is not a directory")
    if not parent.is_dir():
        raise ConfigError(f"cannot write the plot {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise ConfigError(f"cannot write the plot {path}: permission denied")
    if importlib.util.find_spec("matplotlib") is None:
        raise ConfigError("--plot needs matplotlib: pip install 'pyethercat[plot]'")


class Sync0Spread:
    """The SYNC0 spread of an in-process simulator over a run, sampled as it goes.

    The segment keeps only each slave's last pulses (``sim.dc_sync.RECORDED_PULSES``),
    so :meth:`sample` is called every refresh of the live view and the
    series is the union of what it saw. The loop's thread writes the
    records while a sample reads them: the newest and the oldest pulses of
    a sample may be half written (the system time of the new pulse beside
    the true time of the one its slot held), so each sample drops them.
    """

    EDGE = 2

    def __init__(self, segment: Any) -> None:
        self._segment = segment
        self._seen: dict[int, float] = {}

    def sample(self) -> None:
        """Take in the pulses the segment holds now."""
        spreads = self._segment.dc.sync.sync0_spreads()
        for st, spread in spreads[self.EDGE: len(spreads) - self.EDGE]:
            self._seen[st] = spread

    def series(self) -> list[tuple[float, float]]:
        """(seconds since the first pulse seen, spread in ns), in order."""
        if not self._seen:
            return []
        keys = sorted(self._seen)
        return [((k - keys[0]) / 1e9, self._seen[k]) for k in keys]


def plot_dc(path: str, report: DcReport | None, cycle: DcCycle | None = None,
            sync0_spread: Sequence[tuple[float, float]] | None = None, title: str = "") -> int:
    """Write the figure to ``path``; returns the number of panels drawn."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ConfigError("--plot needs matplotlib: pip install 'pyethercat[plot]'") from None
    panels = []
    if report is not None and report.trace:
        panels.append("trace")
    if cycle is not None and cycle.monitor.history:
        panels.append("monitor")
    if cycle is not None and cycle.lock is not None and cycle.lock.history:
        panels.append("phase")
    if sync0_spread:
        panels.append("spread")
    if not panels:
        raise ConfigError("nothing to plot: no DC data was recorded")
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.8 * len(panels)), squeeze=False)
    for ax, kind in zip(axes[:, 0], panels, strict=True):
        if kind == "trace":
            assert report is not None
            follow = report.synchronised
            xs = [n for _t, n, _v in report.trace]
            for k, r in enumerate(follow):
                ys = [max(v[k] or 0, 1) for _t, _n, v in report.trace]
                ax.plot(xs, ys, linewidth=1, label=f"{r.position} {r.name[:18]}")
            ax.set_yscale("log")
            ax.set_xlabel("FRMW sent (static drift compensation)")
            ax.set_ylabel("|0x092C| ns")
            ax.set_title("system time difference per slave during the compensation")
            if len(follow) <= 12:
                ax.legend(fontsize="x-small", ncol=2)
        elif kind == "monitor":
            assert cycle is not None
            t0 = cycle.monitor.history[0][0]
            ax.plot([(t - t0) / 1e9 for t, _ in cycle.monitor.history],
                    [max(b, 1) for _, b in cycle.monitor.history], drawstyle="steps-post")
            ax.axhline(cycle.monitor.limit_ns, color="red", linestyle=":", label="limit")
            ax.set_yscale("log")
            ax.set_xlabel("s")
            ax.set_ylabel("max |0x092C| ns")
            ax.set_title("sync monitor (broadcast read of 0x092C, upper bound)")
            ax.legend(fontsize="x-small")
        elif kind == "phase":
            assert cycle is not None and cycle.lock is not None
            errs = list(cycle.lock.history)
            ax.plot(range(len(errs)), [e / 1000 for e in errs], linewidth=0.8)
            ax.set_xlabel(f"cycle (last {len(errs)})")
            ax.set_ylabel("phase error us")
            ax.set_title("master cycle against the reference clock (0 = on target)")
        else:
            assert sync0_spread is not None
            ax.plot([t for t, _ in sync0_spread], [s for _, s in sync0_spread], linewidth=0.8)
            ax.set_xlabel("s")
            ax.set_ylabel("ns")
            ax.set_title("SYNC0 spread: latest minus earliest pulse of each cycle (simulator)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return len(panels)
