"""The README's Python examples run as written (the daemon one starts a real av-daemon)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_the_readme_has_python_examples() -> None:
    blocks = _python_blocks()
    assert len(blocks) >= 2
    assert any("from rover_env import RoverEnv, RoverEnvFused, DiscreteRoverEnvFused" in b
               for b in blocks)  # fmt: skip


@pytest.mark.parametrize("index", range(len(_python_blocks())))
def test_readme_python_block_runs(index: int, capsys: pytest.CaptureFixture[str]) -> None:
    code = _python_blocks()[index]
    exec(compile(code, f"README.md python block {index}", "exec"), {"__name__": "__readme__"})
    if "fused_image" in code and "print(" in code:
        assert "(96, 96, 3)" in capsys.readouterr().out


def test_public_api_names() -> None:
    import rover_env
    from rover_env import DiscreteRoverEnvFused, RoverEnv, RoverEnvFused

    for cls in (RoverEnv, RoverEnvFused, DiscreteRoverEnvFused):
        assert cls.__name__ in rover_env.__all__
    import active_vision

    assert callable(active_vision.spawn_daemon)
    assert "spawn_daemon" in active_vision.__all__
