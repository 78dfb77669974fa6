"""The command line as an IgH ``ethercat`` user knows it: verbs, options, selection, formats.

Formats are checked against what IgH's ``tool/Command*.cpp`` print (the
comments quote the IgH help texts); ``cstruct`` output is compiled with the
C compiler against the ``ecrt.h`` structure layout.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli._select import parse_list, select
from pyethercat.cli.main import _matches, cli, normalize_argv
from pyethercat.clock import WallClock
from pyethercat.errors import ConfigError
from pyethercat.link.udp import UdpLink
from pyethercat.sim.server import SimServer
from pyethercat.sim.topology import load_topology
from pyethercat.wire.sii import parse_sii

REPO = Path(__file__).resolve().parents[2]
DEMO = str(REPO / "examples" / "demo.toml")
COE = str(REPO / "examples" / "coe.toml")


def run(*args: str, stdin: bytes | None = None) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), input=stdin, catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def raw(*args: str) -> bytes:
    return CliRunner().invoke(cli, list(args), catch_exceptions=False).stdout_bytes


# --- verbs and options -------------------------------------------------------------------


def test_verbs_match_as_in_igh() -> None:
    verbs = ["alias", "config", "crc", "cstruct", "data", "domains", "download", "reg_read",
             "reg_write", "slaves", "sdos", "sii_read", "sii_write", "states", "upload"]
    assert _matches("slaves", verbs) == ["slaves"]  # exact
    assert _matches("sl", verbs) == ["slaves"]  # unique prefix
    assert _matches("up", verbs) == ["upload"]
    assert _matches("cs", verbs) == ["cstruct"]
    assert _matches("sdo", verbs) == ["sdos"]
    assert _matches("dl", verbs) == ["download"]  # letters in order (IgH matchesAbbrev)
    assert _matches("c", verbs) == ["config", "crc", "cstruct"]  # ambiguous


def test_options_before_and_after_the_verb() -> None:
    verbs = ["upload", "slaves", "sim"]
    values = frozenset({"-p", "--position", "-t", "--type"})
    assert normalize_argv(["-p", "1", "upload", "--iface", "eth0", "0x1018", "1"], verbs,
                          values) == ["--iface", "eth0", "upload", "-p", "1", "0x1018", "1"]
    assert normalize_argv(["upload", "--sim=x.toml", "--direct", "-p0", "1", "2"], verbs,
                          values) == ["--sim=x.toml", "--direct", "upload", "-p0", "1", "2"]
    # The simulator's own --iface stays with it.
    assert normalize_argv(["sim", "t.toml", "--iface", "veth0"], verbs, values) == [
        "sim", "t.toml", "--iface", "veth0"]


def test_prefixes_and_options_anywhere_work_end_to_end() -> None:
    code, out, _ = run("sl", "--sim", DEMO)
    assert code == 0 and len(out.splitlines()) == 6
    code, out2, _ = run("-p", "2", "sla", "--sim", DEMO)
    assert out2.splitlines() == [out.splitlines()[2]]


def test_number_lists_and_alias_selection_as_igh() -> None:
    assert parse_list("3", 9) == [3]
    assert parse_list("1,4", 9) == [1, 4]
    assert parse_list("5-7,9", 9) == [5, 6, 7, 9]
    assert parse_list("-3", 9) == [0, 1, 2, 3]
    assert parse_list("7-", 9) == [7, 8, 9]
    assert parse_list("-", 4) == [0, 1, 2, 3, 4]
    assert parse_list("7-5", 9) == [5, 6, 7]
    with pytest.raises(ConfigError, match="invalid character 'x'"):
        parse_list("1x", 9)
    # Aliases by ring position: IgH's example, 5555 at position 1 and 7 at 4.
    aliases = [0, 5555, 0, 0, 7, 0]
    assert select(aliases, None, None) == [0, 1, 2, 3, 4, 5]
    assert select(aliases, "2", None) == [2]
    assert select(aliases, None, "5555") == [1, 2, 3]  # the alias and the slaves behind it
    assert select(aliases, "0", "5555") == [1]
    assert select(aliases, "2", "5555") == [3]
    assert select(aliases, "1", "7") == [5]
    assert select(aliases, "9", "7") == []


# --- formats -------------------------------------------------------------------------------


def test_slaves_lines_as_igh() -> None:
    # "1  5555:0  PREOP  +  EL3162 2C. Ana. Input 0-10V" (IgH CommandSlaves help).
    code, out, _ = run("--sim", DEMO, "slaves")
    lines = out.splitlines()
    assert lines[0] == "0  0:0  INIT  +  PEC-CU4 EtherCAT coupler, 4 ports"
    assert lines[5] == "5  0:5  INIT  +  PEC-AI2 2Ch. analog input 16 bit"
    code, out, _ = run("--sim", DEMO, "slaves", "-p", "1-2")
    assert [ln.split()[0] for ln in out.splitlines()] == ["1", "2"]


def test_reg_read_and_reg_write_with_types() -> None:
    # IgH's outputData: "0x%04x %d" for uint16; the type gives the size.
    code, out, _ = run("--sim", DEMO, "reg_read", "-p", "1", "-t", "uint16", "0x0130")
    assert out == "0x0001 1\n"
    code, out, _ = run("--sim", DEMO, "reg_read", "-p", "1", "-t", "raw", "0x0130", "2")
    assert out == "0x01 0x00\n"
    code, out, _ = run("--sim", DEMO, "reg_read", "-p", "1", "-t", "int32", "0x0000")
    assert code == 0 and out.startswith("0x")
    code, out, _ = run("--sim", DEMO, "reg_write", "-p", "1", "-t", "uint16", "0x0F80", "0x1234")
    assert code == 0 and "wrote 2 bytes at 0x0F80" in out


def test_sii_read_binary_and_sii_write_from_stdin(tmp_path: Path) -> None:
    image = raw("--sim", DEMO, "sii_read", "-p", "2")
    assert parse_sii(image).device_name == "PEC-DI8 8Ch. digital input"
    assert raw("--sim", DEMO, "sii_read", "-p", "2", "-o", "-") == image
    code, out, _ = run("--sim", DEMO, "sii_write", "-p", "2", "-", stdin=image)
    assert code == 0 and "already holds this image; nothing written" in out
    assert "saved to" not in out  # nothing to change, nothing saved


def test_graph_is_igh_dot() -> None:
    code, out, _ = run("--sim", DEMO, "graph")
    lines = out.splitlines()
    assert lines[0] == "/* EtherCAT bus graph. Generated by 'pyethercat graph'. */"
    assert "strict graph bus {" in lines and lines[-1] == "}"
    assert '    master -- slave0[label="MII"]' in lines
    assert '    slave0 [shape="box",label="0 / 0:0\\nPEC-CU4"]' in lines
    # The branch on the coupler's port 3 is slave 1; port 1 leads to slave 2 (E-Bus).
    assert ('    slave0 -- slave1 [taillabel="3",headlabel="0",label="MII",weight="1"]'
            in lines)
    assert ('    slave0 -- slave2 [taillabel="1",headlabel="0",label="EBUS",weight="5"]'
            in lines)
    assert sum(" -- slave" in ln for ln in lines) == 6  # master + 5 cables
    code, out, _ = run("--sim", DEMO, "graph", "CRC")
    assert 'taillabel="1 [0/0]"' in out


def test_crc_table_as_igh() -> None:
    code, out, _ = run("--sim", DEMO, "crc")
    lines = out.splitlines()
    assert lines[0] == "   |Port 0         |Port 1         |Port 2         |Port 3         |"
    assert lines[1] == "   |CRC PHY FWD NXT|CRC PHY FWD NXT|CRC PHY FWD NXT|CRC PHY FWD NXT|"
    assert lines[3].startswith("  1|  0   0   0   ↑|")
    assert len(lines) == 8
    code, out, _ = run("--sim", DEMO, "crc", "reset")
    assert code == 0 and out == ""


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_cstruct_compiles_against_the_ecrt_layout(tmp_path: Path) -> None:
    code, out, _ = run("--sim", DEMO, "cstruct", "-p", "1-2")
    assert "ec_sync_info_t slave_1_syncs[] = {" in out
    # The types of IgH's ecrt.h (field order as there).
    header = """#include <stdint.h>
#include <stdio.h>
typedef enum {EC_DIR_INVALID, EC_DIR_OUTPUT, EC_DIR_INPUT, EC_DIR_COUNT} ec_direction_t;
typedef enum {EC_WD_DEFAULT, EC_WD_ENABLE, EC_WD_DISABLE} ec_watchdog_mode_t;
typedef struct {uint16_t index; uint8_t subindex; uint8_t bit_length;} ec_pdo_entry_info_t;
typedef struct {uint16_t index; unsigned int n_entries; ec_pdo_entry_info_t *entries;}
    ec_pdo_info_t;
typedef struct {uint8_t index; ec_direction_t dir; unsigned int n_pdos; ec_pdo_info_t *pdos;
    ec_watchdog_mode_t watchdog_mode;} ec_sync_info_t;
"""
    main = """
static unsigned bits(ec_sync_info_t *s) {
    unsigned n = 0;
    for (; s->index != 0xff; s++)
        for (unsigned p = 0; p < s->n_pdos; p++)
            for (unsigned e = 0; e < s->pdos[p].n_entries; e++)
                n += s->pdos[p].entries[e].bit_length;
    return n;
}
int main(void) { printf("%u %u\\n", bits(slave_1_syncs), bits(slave_2_syncs)); return 0; }
"""
    src = tmp_path / "c.c"
    src.write_text(header + out + main)
    exe = tmp_path / "c"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(src)], check=True,
                   capture_output=True, text=True)
    # PEC-DO8: 8 output bits; PEC-DI8: 8 input bits.
    assert subprocess.run([str(exe)], capture_output=True, text=True).stdout.split() == ["8", "8"]


def test_version_and_direct_master_views() -> None:
    code, out, _ = run("version")
    assert out.startswith("pyethercat ")
    code, out, err = run("--sim", DEMO, "master")
    assert out.splitlines()[:4] == ["Master0", "  Phase: Idle", "  Active: no", "  Slaves: 6"]
    for verb in ("domains", "config"):
        code, out, err = run("--sim", DEMO, verb)
        assert code == 0 and out == "" and "no master runs on sim:" in err
    code, out, _ = run("--sim", DEMO, "rescan", "-v")
    assert out == "6 slaves\n"


# --- alias and SII writes against a simulator that keeps its EEPROM ----------------------------


@pytest.fixture
def udp_segment(tmp_path: Path, patient_cli: None) -> Iterator[str]:
    """The EK1100 + EL2004 of the corpus served over UDP (state kept between commands)."""
    corpus = REPO.parent / "shared" / "corpus" / "sii"
    topo = tmp_path / "t.toml"
    topo.write_text(f'[[slave]]\nname = "ek"\nsii = "{corpus / "ethercrab_ek1100.bin"}"\n'
                    f'[[slave]]\nname = "el"\nsii = "{corpus / "ethercrab_el2004.bin"}"\n')
    seg = load_topology(topo).build()
    seg.clock = WallClock()  # real EEPROM timing against a real-time master
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(seg, link)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    host, port = link.address
    try:
        yield f"{host}:{port}"
    finally:
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()


def test_alias_is_written_kept_and_backed_up(udp_segment: str, tmp_path: Path) -> None:
    code, out, _ = run("--udp", udp_segment, "alias", "-p", "1", "4711")
    assert code == 0, out
    backup = next(ln.split(" saved to ")[1] for ln in out.splitlines() if " saved to " in ln)
    assert Path(backup).is_file() and Path(backup).parent.name == "sii-backup"
    assert "wrote 2 of" in out and "alias 4711" in out
    # IgH's alias:position column now counts from the new alias.
    code, out, _ = run("--udp", udp_segment, "slaves")
    assert [ln.split()[1] for ln in out.splitlines()] == ["0:0", "4711:0"]
    code, out, _ = run("--udp", udp_segment, "-a", "4711", "reg_read", "-t", "uint16", "0x0012")
    assert out == "0x1267 4711\n"
    # The backup restores the old EEPROM (alias 0).
    code, out, _ = run("--udp", udp_segment, "sii_write", "-p", "1", backup)
    assert code == 0 and "alias 0" in out
    code, out, err = run("--udp", udp_segment, "alias", "-a", "4711", "5")
    assert code == 0 and "the selection matches no slaves" in err  # the alias is gone


def test_sii_write_refuses_another_device_unless_forced(udp_segment: str, tmp_path: Path) -> None:
    ek = raw("--udp", udp_segment, "sii_read", "-p", "0")
    el = tmp_path / "el.bin"
    el.write_bytes(raw("--udp", udp_segment, "sii_read", "-p", "1"))
    code, _, err = run("--udp", udp_segment, "sii_write", "-p", "0", str(el))
    assert code == 1 and "another device" in err and "EEPROM is unchanged" in err
    assert raw("--udp", udp_segment, "sii_read", "-p", "0") == ek
    code, out, _ = run("--udp", udp_segment, "sii_write", "-p", "0", "--force", str(el),
                       "--backup", str(tmp_path / "ek-old.bin"))
    assert code == 0 and "becomes another device: product 0x044C2C52 -> 0x07D43052" in out
    assert (tmp_path / "ek-old.bin").read_bytes()[:len(ek)] == ek
    code, out, _ = run("--udp", udp_segment, "slaves")
    assert out.splitlines()[0].endswith("EL2004 4K. Dig. Ausgang 24V, 0.5A")


# --- config: IgH's selection by alias:position ------------------------------------------------


@pytest.fixture
def aliased_master(tmp_path: Path) -> Iterator[str]:
    """A running master (control socket) on coupler, di8 (alias 7), do8, di8."""
    from pyethercat.link.pair import PairLink
    from pyethercat.master.control.endpoint import link_spec
    from pyethercat.master.control.server import serve
    from pyethercat.master.master import Master

    topo = tmp_path / "aliased.toml"
    topo.write_text('[[slave]]\nname = "c"\ndevice = "builtin:coupler"\n'
                    '[[slave]]\nname = "a"\ndevice = "builtin:di8"\nalias = 7\n'
                    '[[slave]]\nname = "b"\ndevice = "builtin:do8"\n'
                    '[[slave]]\nname = "d"\ndevice = "builtin:di8"\n')
    segment = load_topology(topo).build()
    m = Master(PairLink.responder_link(segment.process))
    m.scan()
    m.configure()
    runner = m.start(0.002)
    server = serve(m, link_spec(sim=str(topo)))
    try:
        yield str(topo)
    finally:
        server.close()
        runner.stop()
        m.close()


def test_config_selects_by_alias_and_position_as_igh(aliased_master: str) -> None:
    def rows(*sel: str) -> list[tuple[str, str]]:
        code, out, err = run("--sim", aliased_master, "config", *sel)
        assert code == 0, err
        return [(ln.split()[0], ln.split()[2]) for ln in out.splitlines()]

    # alias:position, attached ring position
    assert rows() == [("0:0", "0"), ("7:0", "1"), ("7:1", "2"), ("7:2", "3")]
    assert rows("-a", "7", "-p", "1") == [("7:1", "2")]
    assert rows("-a", "7") == [("7:0", "1"), ("7:1", "2"), ("7:2", "3")]
    # -p alone counts within every alias (IgH Command::selectedConfigs)
    assert rows("-p", "0") == [("0:0", "0"), ("7:0", "1")]
    assert rows("-p", "1-2", "-a", "0-7") == [("7:1", "2"), ("7:2", "3")]
    assert rows("-a", "3") == []
    code, out, _ = run("--sim", aliased_master, "config", "-v", "-a", "7", "-p", "2")
    assert out.splitlines()[:3] == ["Alias: 7", "Position: 2", "Vendor Id: 0x00504543"]


def test_a_failing_eeprom_write_prints_the_whole_restore_command(
        tmp_path: Path, patient_cli: None) -> None:
    """The EEPROM keeps a wrong alias word: the error line is a command that can be run as is."""
    corpus = REPO.parent / "shared" / "corpus" / "sii"
    topo = tmp_path / "t.toml"
    topo.write_text(f'[[slave]]\nname = "ek"\nsii = "{corpus / "ethercrab_ek1100.bin"}"\n'
                    f'[[slave]]\nname = "el"\nsii = "{corpus / "ethercrab_el2004.bin"}"\n')
    seg = load_topology(topo).build()
    seg.clock = WallClock()
    eeprom = seg.escs[1].eeprom
    original = bytes(eeprom.image)
    store = eeprom._write_word

    def bad_cell(address: int, now: int) -> None:
        store(address, now)
        if address == 4:  # the alias word: one bit stuck at 1
            eeprom.image[8] |= 0x01

    eeprom._write_word = bad_cell  # type: ignore[method-assign]
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(seg, link)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    where = "{}:{}".format(*link.address)
    try:
        backup = tmp_path / "old.bin"
        code, out, err = run("--udp", where, "alias", "-p", "1", "4710", "--backup", str(backup))
        assert code == 1
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "word 0x0004" in lines[0], err
        restore = f"pyethercat --udp {where} sii_write -p 1 --force {backup}"
        assert lines[0].endswith(f"restore the old content with {restore}"), lines[0]
        saved = backup.read_bytes()
        assert len(saved) > 0x80 and saved == original[:len(saved)]
        # The cell is mended; the printed command, run as it stands, puts the old SII back.
        eeprom._write_word = store  # type: ignore[method-assign]
        code, out, err = run(*restore.split()[1:])
        assert code == 0, err
        assert bytes(eeprom.image[:len(original)]) == original
    finally:
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()
