"""``run --plot FILE.png`` without ``--dc``: the loop's period and jitter distribution.

Two panels from the loop's sample rings (the last 2^18 cycles):

* the distribution of the period (start to start), log-scaled counts, with
  the nominal period marked: a loop that keeps its deadlines is one narrow
  spike; cycles a stall moved show as a tail (the central 99.9 %; how many
  fall outside, and how far, is in the legend);
* the complementary distribution of the jitter |period - nominal| (the
  share of cycles above each value, both axes logarithmic), where p99 and
  p99.9 read off directly.
"""

from __future__ import annotations

import textwrap

import numpy as np

from pyethercat.errors import ConfigError
from pyethercat.master.cyclestats import CycleStats

__all__ = ["plot_cycles"]


def plot_cycles(path: str, stats: CycleStats, title: str = "") -> None:
    """Write the figure to ``path`` (PNG); ConfigError without matplotlib or samples."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ConfigError("--plot needs matplotlib: pip install 'pyethercat[plot]'") from None
    periods = stats.periods()
    if periods.size < 2:
        raise ConfigError("--plot: the run had too few cycles to plot")
    nominal_us = stats.period_ns / 1000
    per_us = periods / 1000.0
    jitter = np.sort(np.abs(per_us - nominal_us))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    # The central 99.9 % of the periods: one stall of many periods would otherwise
    # squeeze the spike into one bin (the right panel shows every cycle).
    lo, hi = (float(v) for v in np.percentile(per_us, [0.05, 99.95]))
    lo, hi = min(lo, nominal_us - 5.0), max(hi, nominal_us + 5.0)
    inside = (per_us >= lo) & (per_us <= hi)
    a.hist(per_us[inside], bins=200, log=True, color="tab:blue")
    a.axvline(nominal_us, color="tab:red", lw=0.8, label=f"nominal {nominal_us:g} us")
    outside = int(per_us.size - inside.sum())
    if outside:
        a.plot([], [], " ", label=f"{outside} outside: {per_us.min():.0f} to "
                                  f"{per_us.max():.0f} us")
    a.set_xlabel("period (us)")
    a.set_ylabel("cycles (log)")
    a.legend(fontsize=8)
    share = 1.0 - np.arange(jitter.size) / jitter.size
    floor = max(float(jitter[jitter > 0].min()) if (jitter > 0).any() else 0.01, 0.01)
    b.loglog(np.maximum(jitter, floor), share, color="tab:blue")
    for q in (99.0, 99.9):
        v = float(np.percentile(jitter, q))
        b.axvline(max(v, floor), color="tab:gray", lw=0.6, ls="--")
        b.text(max(v, floor), 1.0 - q / 100, f" p{q:g} {v:.1f} us", fontsize=8)
    b.set_xlabel("jitter |period - nominal| (us, log)")
    b.set_ylabel("share of cycles above (log)")
    b.grid(True, which="both", lw=0.3)
    # (the loop's description is long: wrapped, not cut at the figure's edges)
    fig.suptitle("\n".join(textwrap.wrap(title or f"{periods.size + 1} cycles", 110)))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
