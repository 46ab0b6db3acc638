"""The batch simulator's Python side and its C driver agree on the driver's interface, and the compiled
library's helpers stay inside the simulation stage."""
import ast
import re
from pathlib import Path

from servofmu.simulation.compiled import DRIVER, HOLD_CODES, SineResult

ROOT = Path(__file__).resolve().parent.parent


def c_enum(text: str, opening: str) -> list[str]:
    """The names of the C enum that begins with ``opening`` (up to its brace), comments removed, in order."""
    body = text[text.index(opening) + len(opening):]
    body = re.sub(r"/\*.*?\*/", "", body[:body.index("}")], flags=re.S)
    return [item.split("=")[0].strip() for item in body.split(",") if item.strip()]


def test_the_sine_result_slots_are_the_drivers_in_its_order():
    names = c_enum(DRIVER.read_text(), "enum SineResult {")
    assert names == [f"SINE_{slot.name}" for slot in SineResult] + ["NF"]
    assert [slot.value for slot in SineResult] == list(range(len(SineResult)))


def test_the_hold_codes_are_the_drivers():
    opening = "enum { HOLD_ZOH"
    body = DRIVER.read_text().split(opening, 1)[1]
    items = [item.split("=") for item in ("HOLD_ZOH" + body[:body.index("}")]).split(",")]
    assert {name.strip(): int(value) for name, value in items} == \
        {f"HOLD_{hold.upper()}": code for hold, code in HOLD_CODES.items()}


def test_nothing_outside_the_simulation_stage_uses_the_compiled_library_or_its_ctypes_helpers():
    private = {"c_doubles", "c_mask", "compiled_driver", "H_START", "batch_library"}
    users = []
    for path in sorted((ROOT / "servofmu").rglob("*.py")):
        if path.parent == ROOT / "servofmu" / "simulation":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and ("simulation.compiled" in (node.module or "")
                                                     or private & {a.name for a in node.names}):
                users.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert users == []
