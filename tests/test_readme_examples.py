"""Every ```python block of README.md runs as written, so the examples cannot rot.

Each block runs in a fresh namespace with a temporary working directory that holds a link to
the bundled ``datasets/``. A block whose first line is ``# needs: WHAT ...`` gets a stand-in:

- ``mpu6050``: ``smbus2.SMBus`` opens a register-level simulated chip
  (:class:`drivers.sim.mpu6050.SimulatedMPU6050`, at rest) instead of ``/dev/i2c-N``;
- ``chassis``: a simulated STM32 (:class:`drivers.sim.stm32.PtyStm32`) on a pseudo-terminal
  replaces ``/dev/ttyUSB0``;
- ``rospy``: not run (the test interpreter has no ROS 1); it must compile and every import
  but rospy's must resolve;
- ``ros2``: runs with DDS pinned to loopback on a fresh ``ROS_DOMAIN_ID`` (conftest's
  ``ros2_env``); skipped without cyclonedds, except under CI.
"""

from __future__ import annotations

import ast
import importlib
import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: README.md has at least this many ```python blocks (a README without them fails)
MIN_BLOCKS = 8
FENCE = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)
NEEDS = re.compile(r"#\s*needs:\s*(\w+)")


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line, code)`` of each ```python block (line: 1-based, of the first code line)."""
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in FENCE.finditer(text)]


BLOCKS = python_blocks(README.read_text(encoding="utf-8"))


def needs(code: str) -> str | None:
    m = NEEDS.match(code.lstrip())
    return m.group(1) if m else None


def test_the_readme_has_its_python_examples_fenced():
    assert len(BLOCKS) >= MIN_BLOCKS, [line for line, _ in BLOCKS]
    # none left in the old style: an indented block with Python imports outside the fences
    unfenced = FENCE.sub("", README.read_text(encoding="utf-8"))
    stray = [line for line in unfenced.splitlines()
             if re.match(r"    +(from \w[\w.]* import |import \w)", line)]
    assert stray == []


def test_ci_runs_exactly_the_readmes_test_command():
    # the README's second command is the suite as a user runs it; .ci/run must not drift
    commands = re.findall(r"^```bash\n(.*?)^```", README.read_text(encoding="utf-8"),
                          re.S | re.M)
    test_command = commands[1].strip()
    assert "pytest" in test_command and "\n" not in test_command
    assert test_command in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()


def test_ci_stops_when_any_part_of_the_readmes_test_command_fails():
    # .ci/run is `set -euo pipefail`, but bash does not stop at a failure inside an && list
    # unless it is the last command: the README's first half failing ran on to the no-numba
    # repeat, which passed, and CI reported success. The line after the README's command must
    # stop the script; run here with each part of an && list of the same shape failing.
    commands = re.findall(r"^```bash\n(.*?)^```", README.read_text(encoding="utf-8"),
                          re.S | re.M)
    lines = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    after = lines.index(commands[1].strip()) + 1
    check = next(line for line in lines[after:] if line and not line.startswith("#"))
    assert "pytest" not in check, f"no status check after the README's command: {check}"
    for shape in ("false && true && true", "true && false && true", "true && true && false"):
        done = subprocess.run(["bash", "-c", f"set -euo pipefail\n{shape}\n{check}\n"
                               "echo reached"], capture_output=True, text=True)
        assert done.returncode != 0 and "reached" not in done.stdout, (shape, check)
    ok = subprocess.run(["bash", "-c", f"set -euo pipefail\ntrue && true\n{check}\n"
                         "echo reached"], capture_output=True, text=True)
    assert ok.returncode == 0 and "reached" in ok.stdout


def test_python_blocks_are_found_with_their_lines():
    text = "a\n```python\nx = 1\ny = 2\n```\n```bash\nls\n```\n```python\n# needs: rospy\n```\n"
    assert python_blocks(text) == [(3, "x = 1\ny = 2\n"), (10, "# needs: rospy\n")]
    assert [needs(code) for _, code in python_blocks(text)] == [None, "rospy"]


def run_block(code: str, line: int) -> dict:
    namespace = {"__name__": "__readme__"}
    exec(compile(code, f"{README}:{line}", "exec"), namespace)
    return namespace


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    (tmp_path / "datasets").symlink_to(ROOT / "datasets", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(("line", "code"), BLOCKS, ids=[f"README.md:{n}" for n, _ in BLOCKS])
def test_readme_python_block_runs(workdir, monkeypatch, request, line, code):
    need = needs(code)
    if need is None:
        run_block(code, line)
    elif need == "mpu6050":
        smbus2 = pytest.importorskip("smbus2")
        from drivers.mpu6050 import SystemClock
        from drivers.sim.mpu6050 import SimulatedMPU6050, static_trace

        chips = []

        def simulated_bus(bus):
            chips.append(SimulatedMPU6050(static_trace(), bus_number=bus, clock=SystemClock()))
            return chips[-1]

        monkeypatch.setattr(smbus2, "SMBus", simulated_bus)
        ns = run_block(code, line)
        assert len(chips) == 1 and chips[0].bus_number == 1
        assert ns["s"].accel.shape == (3,)
    elif need == "chassis":
        from drivers.sim.stm32 import PtyStm32

        assert "/dev/ttyUSB0" in code
        with PtyStm32() as sim:
            run_block(code.replace("/dev/ttyUSB0", sim.data_port), line)
    elif need == "rospy":
        check_imports_resolve(code, line, skip={"rospy"})
    elif need == "ros2":
        if importlib.util.find_spec("cyclonedds") is None and not os.environ.get("CI"):
            pytest.skip("the ros2 extra (cyclonedds) is not installed")
        request.getfixturevalue("ros2_env")
        run_block(code, line)
    else:
        pytest.fail(f"README.md:{line}: unknown '# needs: {need}'")


def check_imports_resolve(code: str, line: int, skip: set[str]) -> None:
    """Compile ``code`` and import each module and name it imports (but those of ``skip``)."""
    tree = ast.parse(compile(code, f"{README}:{line}", "exec", ast.PyCF_ONLY_AST))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] not in skip:
                    importlib.import_module(alias.name)
        elif isinstance(node, ast.ImportFrom) and node.module.split(".")[0] not in skip:
            module = importlib.import_module(node.module)
            for alias in node.names:
                assert hasattr(module, alias.name) or importlib.util.find_spec(
                    f"{node.module}.{alias.name}"), f"README.md:{line}: {alias.name}"


def test_first_read_after_configuration_is_in_the_configured_range():
    from drivers.mpu6050 import MPU6050
    from drivers.sim.mpu6050 import SimulatedMPU6050, static_trace

    sim = SimulatedMPU6050(static_trace())  # at rest, z up: +1 g on z
    imu = MPU6050(sim, 0x68, gyro_range_dps=500, accel_range_g=4, sample_rate_hz=100,
                  clock=sim.clock)
    assert imu.read().accel[2] == pytest.approx(9.80665, abs=0.01)


def test_the_readme_lists_every_trust_warning_the_code_raises():
    """The README's `warning: inputs disagree (a | b | ...)` list against every
    TrustWarning("name", ...) the package's source constructs."""
    listed = re.search(r"`warning: inputs disagree \(([a-z_ |\n]+)\): \.\.\.`",
                       README.read_text())
    assert listed, "the README's list of trust warnings is gone"
    readme = {n.strip() for n in listed.group(1).split("|")}
    raised = set()
    for path in (ROOT / "fusion").rglob("*.py"):
        raised |= set(re.findall(r'TrustWarning\(\s*"([a-z_]+)"', path.read_text()))
    assert len(raised) > 10
    assert readme == raised, (sorted(readme - raised), sorted(raised - readme))
