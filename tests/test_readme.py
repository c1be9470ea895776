"""The README's first steps: the expected time beside the first command (as the experiment's
config states it), the CPU torch note before the first install, pasteable commands."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
PAPER = (REPO / "src" / "hysteresis_lab" / "conf" / "experiment" / "paper.yaml").read_text()
CI_RUN = (REPO / ".ci" / "run").read_text()


def quick_start_commands() -> list[str]:
    """The command lines of the quick start's code block."""
    section = README.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.S)
    assert block, "the quick start has no bash block"
    return [line.split("   #", 1)[0].rstrip() for line in block.group(1).splitlines() if line]


def test_the_first_command_gives_the_time_the_paper_config_gives():
    line = next(x for x in README.splitlines() if "hysteresis-lab-train experiment=paper" in x)
    readme_time = re.search(r"about ([\d–-]+ min)", line)
    config_time = re.search(r"experiment=paper\s+\(about ([\d–-]+ min)", PAPER)
    assert readme_time and config_time and readme_time.group(1) == config_time.group(1)


def test_the_cpu_torch_note_comes_before_the_first_install():
    note = README.index("download.pytorch.org/whl/cpu")
    assert note < README.index("pip install -e .")


def test_ci_runs_the_second_command_word_for_word_in_a_fresh_venv_after_pinned_torch():
    first, second = quick_start_commands()
    assert first == "pip install -e . && hysteresis-lab-train experiment=paper"
    lines = [line.strip() for line in CI_RUN.splitlines()]
    assert lines[-1] == second  # the suite is the last thing CI runs, as users type it

    def line_of(pattern: str) -> int:
        return next(i for i, line in enumerate(lines) if re.fullmatch(pattern, line))

    venv = line_of(r".*python\S*\"? -m venv .*")
    activate = line_of(r"(source|\.) .*/bin/activate\"?")
    torch = line_of(r"pip install torch==[\d.]+")
    assert venv < activate < torch < len(lines) - 1
    pin = lines[torch].split()[-1]
    assert f"`{pin}`" in README and "fresh virtual environment" in README


def test_every_command_line_in_the_code_blocks_is_pasteable():
    blocks = re.findall(r"```bash\n(.*?)```", README, flags=re.S)
    for line in "\n".join(blocks).splitlines():
        command = line.split("#", 1)[0]
        assert not re.search(r"\bdata=\w+ \| data=", command), line


def test_the_study_is_cited_once_with_authors_title_venue_and_year():
    assert README.count("Deep learning applied to data-driven dynamic characterization") == 1
    assert "Soares Barbosa" in README and "IFAC World Congress" in README and "2020" in README
