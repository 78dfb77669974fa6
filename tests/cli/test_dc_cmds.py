"""``pyethercat dc`` and ``run --dc`` against the in-process simulator (demo segment)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def rows(out: str) -> list[list[str]]:
    return [line.split() for line in out.splitlines() if line[:1].isdigit()]


def test_dc_sets_up_and_lists_every_slave(tmp_path: Path) -> None:
    plot = tmp_path / "dc.png"
    code, out, err = run("--sim", str(DEMO), "dc", "--static", "600", "--sync0", "500",
                         "--shift", "20", "--plot", str(plot))
    assert code == 0, out + err
    lines = out.splitlines()
    assert lines[0].startswith("# reference clock: slave 0 (0x1001, PEC-CU4")
    assert "600 FRMW in 9 frames" in lines[1]
    table = rows(out)
    assert len(table) == 6
    # pos station dc ref entry parent delay offset diff sync...
    assert [r[3] for r in table] == ["*", "-", "-", "-", "-", "-"]
    assert all(r[2] == "64-bit" for r in table)
    assert [r[5] for r in table] == ["-", "0:3", "0:1", "2:1", "3:1", "4:1"]
    delays = [int(r[6]) for r in table]
    # the branch on port 3 comes first; then the E-Bus line, each one further away
    assert delays[0] == 0 and delays[1] > 0 and delays[2] < delays[3] < delays[4] < delays[5]
    assert table[0][9] == "off"  # the coupler has no DC op mode
    for r in table[1:]:
        assert r[9:13] == ["SYNC0", "(0x0300)", "cycle0", "500000"]
        assert int(r[-1]) % 500_000 == 20_000  # start time on the grid, shifted
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_dc_errors_are_one_line() -> None:
    code, out, err = run("--sim", str(DEMO), "dc", "--reference", "9", "--static", "0")
    assert code == 1 and err.startswith("pyethercat: error: reference clock: slave 9")
    code, out, err = run("--sim", str(DEMO), "dc", "--static", "0", "--sync0", "1000",
                         "--sync1", "1500")
    assert code == 1 and "--sync1 1500 us" in err


@pytest.mark.parametrize("mode", ["master", "reference"])
def test_run_dc_shows_the_dc_state(mode: str, tmp_path: Path) -> None:
    plot = tmp_path / "run.png"
    code, out, err = run("--sim", str(DEMO), "run", "--dc", "--dc-mode", mode, "--cycle", "2000",
                         "--seconds", "0.6", "--plot", str(plot))
    assert code == 0, out + err
    dc_lines = [line for line in out.splitlines() if line.startswith(f"DC {mode}: ")]
    assert dc_lines, out
    if mode == "master":
        # (in reference mode the host's send jitter, large for an in-process
        # simulator on a busy machine, goes straight into the reference clock)
        assert dc_lines[-1].endswith("in sync")
    assert "WKC errors: 0" in out
    assert plot.exists()


def test_slaves_verbose_shows_dc_as_igh_does(tmp_path: Path, corpus_dir: Path) -> None:
    topo = tmp_path / "t.toml"
    topo.write_text("".join(
        f'[[slave]]\nname = "{n}"\nsii = "{corpus_dir / "sii" / f"ethercrab_{n}.bin"}"\n'
        for n in ("ek1100", "el2828", "el2889")))
    code, out, err = run("--sim", str(topo), "slaves", "-v")
    assert code == 0, out + err
    records = out.split("=== Slave ")
    assert "Distributed clocks: yes, 64 bit\nDC system time transmission delay: 0 ns" in records[1]
    assert "Distributed clocks: yes, delay measurement only" in records[2]  # EL2828
    # after a set-up: the EL2889's delay, half the EK1100's round trip behind port 1
    # (595 ns, read in 10 ns ticks as 590 or 600 depending on the clock's phase,
    # as on the real slaves); the EL2828 has no delay register
    code, out, err = run("--sim", str(topo), "dc", "--static", "0")
    assert code == 0, out + err
    delays = [r[6] for r in rows(out)]
    assert delays[:2] == ["0", "-"] and delays[2] in ("295", "300")


def test_run_dc_plot_has_the_sync0_spread_of_the_simulator(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With --sim the plot gets the SYNC0 spread panel from the pulses the segment recorded."""
    import matplotlib.figure

    from pyethercat.cli import dc_plot

    drawn: list[list[str]] = []
    spreads: list[list[tuple[float, float]]] = []
    save = matplotlib.figure.Figure.savefig
    plot_dc = dc_plot.plot_dc

    def savefig(fig: matplotlib.figure.Figure, *args: object, **kw: object) -> None:
        drawn.append([ax.get_title() for ax in fig.axes])
        save(fig, *args, **kw)  # type: ignore[arg-type]

    def spy(*args: object, **kw: object) -> int:
        spreads.append(list(kw.get("sync0_spread") or []))  # type: ignore[call-overload]
        return plot_dc(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    monkeypatch.setattr(dc_plot, "plot_dc", spy)
    plot = tmp_path / "run.png"
    code, out, err = run("--sim", str(DEMO), "run", "--dc", "--cycle", "2000", "--seconds", "1.5",
                         "--plot", str(plot))
    assert code == 0, out + err
    assert len(drawn) == 1 and drawn[0][-1].startswith("SYNC0 spread"), drawn
    series = spreads[0]
    # pulses of 2 ms cycles from several refreshes of the live view, in time order
    assert len(series) > 20 and [t for t, _ in series] == sorted(t for t, _ in series)
    assert series[-1][0] > 0.3
    # the five terminals with a DC op mode fire together (an in-process simulator on the
    # host's clock: within a few microseconds, not a cycle apart)
    assert all(0 <= s < 20_000 for _, s in series), max(s for _, s in series)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_slaves_verbose_shows_the_delay_dc_wrote(tmp_path: Path, corpus_dir: Path,
                                                 patient_cli: None) -> None:
    """One simulated segment kept between commands (over UDP): after ``dc``, ``slaves -v``
    shows the EL2889's delay from its 0x0928, as IgH's tool does after the master's set-up."""
    import threading

    from pyethercat.clock import WallClock
    from pyethercat.link.udp import UdpLink
    from pyethercat.sim.server import SimServer
    from pyethercat.sim.topology import load_topology

    topo = tmp_path / "t.toml"
    topo.write_text("".join(
        f'[[slave]]\nname = "{n}"\nsii = "{corpus_dir / "sii" / f"ethercrab_{n}.bin"}"\n'
        for n in ("ek1100", "el2828", "el2889")))
    seg = load_topology(topo).build()
    seg.clock = WallClock()  # real EEPROM timing against a real-time master
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(seg, link)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    where = "{}:{}".format(*link.address)

    def delays(out: str) -> list[str]:
        return [rec.split("DC system time transmission delay: ")[1].split()[0]
                if "transmission delay" in rec else "-" for rec in out.split("=== Slave ")[1:]]

    try:
        code, out, err = run("--udp", where, "slaves", "-v")
        assert code == 0, err
        assert delays(out) == ["0", "-", "0"]  # nobody measured yet
        code, out, err = run("--udp", where, "dc", "--static", "0")
        assert code == 0, err
        measured = [r[6] for r in rows(out)]
        assert measured[:2] == ["0", "-"] and measured[2] in ("295", "300")
        code, out, err = run("--udp", where, "slaves", "-v")
        assert code == 0, err
        assert delays(out) == ["0", "-", measured[2]]
    finally:
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()
