"""The public surface: what ``import pyethercat`` offers, what it loads, ``__all__`` everywhere."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pyethercat


def _loaded_after(code: str) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys\n"
         "print('\\n'.join(m for m in sys.modules if m.startswith('pyethercat')))"],
        capture_output=True, text=True, check=True,
    ).stdout
    return set(out.split())


def test_import_is_light_and_master_does_not_load_the_simulator() -> None:
    assert _loaded_after("import pyethercat") == {"pyethercat", "pyethercat.errors"}
    after_master = _loaded_after("import pyethercat; pyethercat.Master; pyethercat.Slave")
    assert "pyethercat.master.master" in after_master
    assert not any(m.startswith("pyethercat.sim") for m in after_master)
    after_sim = _loaded_after("from pyethercat import Segment, load_topology")
    assert "pyethercat.sim.segment" in after_sim
    assert not any(m.startswith("pyethercat.master") for m in after_sim)


def test_top_level_names() -> None:
    from pyethercat.errors import EtherCATError
    from pyethercat.master.master import Master
    from pyethercat.master.slave import Slave
    from pyethercat.sim.segment import Segment
    from pyethercat.sim.topology import load_topology
    from pyethercat.wire.al import AlState

    assert pyethercat.Master is Master and pyethercat.Slave is Slave
    assert pyethercat.AlState is AlState and pyethercat.EtherCATError is EtherCATError
    assert pyethercat.Segment is Segment and pyethercat.load_topology is load_topology
    assert issubclass(pyethercat.errors.SdoAbort, EtherCATError)
    assert set(pyethercat.__all__) <= set(dir(pyethercat))
    try:
        pyethercat.NoSuchThing  # type: ignore[attr-defined]  # noqa: B018
    except AttributeError as exc:
        assert "NoSuchThing" in str(exc)
    else:
        raise AssertionError("unknown attribute did not raise")


def test_every_module_declares_all_and_its_names_exist() -> None:
    missing, broken = [], []
    for info in pkgutil.walk_packages(pyethercat.__path__, "pyethercat."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        names = getattr(module, "__all__", None)
        if names is None:
            missing.append(info.name)
            continue
        broken += [f"{info.name}.{n}" for n in names if not hasattr(module, n)]
    assert missing == []
    assert broken == []


def test_a_public_class_name_means_one_thing() -> None:
    # Two classes of one name in two modules (a master's and a simulator's FmmuConfig)
    # make imports, tracebacks and the docs ambiguous.
    import ast
    from collections import defaultdict
    from pathlib import Path

    root = Path(pyethercat.__file__).parent
    where: dict[str, list[str]] = defaultdict(list)
    for path in sorted(root.rglob("*.py")):
        for node in ast.parse(path.read_text("utf-8")).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                where[node.name].append(str(path.relative_to(root)))
    assert {name: files for name, files in where.items() if len(files) > 1} == {}
