"""The README is the front door: short, its commands extractable exactly as ``.ci/run``
extracts them, its code runs, its links resolve; the docs command installs what the gallery
needs; ``docs/check_links.py`` catches what the built site must not hold."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 250


def ci_readme_command(marker: str) -> str:
    """The command between ``<!-- marker -->`` markers, by ``.ci/run``'s own function."""
    script = (ROOT / ".ci" / "run").read_text()
    function = re.search(r"^readme_command\(\) \{\n.*?^\}\n", script, flags=re.S | re.M)
    assert function is not None, ".ci/run has no readme_command function"
    done = subprocess.run(
        ["bash", "-c", f"{function.group(0)}\nreadme_command {marker}"],
        cwd=ROOT, capture_output=True, text=True, check=True,
    )  # fmt: skip
    return done.stdout.strip()


def readme_block(marker: str) -> str:
    """The fenced python code between ``<!-- marker -->`` and ``<!-- /marker -->``."""
    match = re.search(
        rf"<!-- {marker} -->\s*```python\n(.*?)```\s*<!-- /{marker} -->",
        README.read_text(),
        flags=re.S,
    )
    assert match is not None, f"README has no python block between <!-- {marker} --> markers"
    return match.group(1)


def test_readme_fits_on_a_few_screens() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines (at most {MAX_LINES})"


@pytest.mark.skipif(shutil.which("bash") is None or shutil.which("awk") is None, reason="bash")
@pytest.mark.parametrize("marker", ["main-command", "test-command", "docs-command"])
def test_each_command_is_one_line_ci_can_extract(marker: str) -> None:
    command = ci_readme_command(marker)
    assert command, f"no command between <!-- {marker} --> markers"
    assert len(command.splitlines()) == 1, command
    assert command.startswith("python -m pip install "), command
    text = README.read_text()
    assert text.count(f"<!-- {marker} -->") == 1 and text.count(f"<!-- /{marker} -->") == 1


def test_docs_command_installs_torch_first_and_the_docs_extra() -> None:
    command = ci_readme_command("docs-command")
    steps = [step.strip() for step in command.split("&&")]
    assert steps[0] == "python -m pip install torch==2.13.0", "the pinned CPU torch first"
    assert 'python -m pip install -e ".[docs]"' in steps
    assert steps[-1].startswith("python -m sphinx -W"), "warnings are errors"


def _docs_requirements() -> set[str]:
    """Distribution names the ``docs`` extra installs (its own extras expanded)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras, name = project["optional-dependencies"], project["name"]
    found: set[str] = set()
    todo, seen = ["docs"], set()
    while todo:
        extra = todo.pop()
        seen.add(extra)
        for requirement in extras[extra]:
            match = re.match(r"([A-Za-z0-9_.-]+)(?:\[([^\]]*)\])?", requirement)
            assert match is not None, requirement
            dist = match.group(1).lower().replace("_", "-")
            if dist == name.lower().replace("_", "-"):
                todo += [e.strip() for e in (match.group(2) or "").split(",") if e not in seen]
            else:
                found.add(dist)
    return found | {re.split(r"[<>=!~ ;\[]", d)[0].lower() for d in project["dependencies"]}


# what a gallery example imports -> the distribution that must come with the docs extra
_NEEDS = {
    "torch": "torch",
    "pyarrow": "pyarrow",
    "ltv_lstm_mpc.training.train": "torch",  # train() is the library's torch user
    "ltv_lstm_mpc.campaign": "pyarrow",  # traces as Parquet
    "matplotlib": "matplotlib",
    "numpy": "numpy",
}


def test_docs_extra_holds_what_the_gallery_imports() -> None:
    """The former defect: ``.[docs]`` lacked torch and pyarrow, so the README's docs
    command failed in a fresh venv (CI passed only after the test command's install)."""
    installed = _docs_requirements()
    assert {"sphinx", "sphinx-gallery", "sphinx-mathjax-offline"} <= installed
    for example in sorted((ROOT / "docs" / "examples").glob("plot_*.py")):
        for node in ast.walk(ast.parse(example.read_text())):
            names = (
                [alias.name for alias in node.names] if isinstance(node, ast.Import)
                else [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            )  # fmt: skip
            for module in names:
                for prefix, dist in _NEEDS.items():
                    if module == prefix or module.startswith(prefix + "."):
                        assert dist in installed, f"{example.name} imports {module}: {dist}"


def test_readme_relative_links_resolve() -> None:
    """Every relative link of the README names a file or folder of the repository, and a
    ``#fragment`` into a markdown page names one of its headings (GitHub's anchors)."""
    text = README.read_text()
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    assert links
    for link in links:
        if re.match(r"[a-z]+://", link) or link.startswith("mailto:"):
            continue
        path, _, fragment = link.partition("#")
        target = ROOT / path if path else README
        assert target.exists(), f"README links to {link}: no {target}"
        if fragment and target.suffix == ".md":
            headings = re.findall(r"^#{1,6} (.+)$", target.read_text(), flags=re.M)
            anchors = {
                re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings
            }
            assert fragment in anchors, f"README links to {link}: no such heading"


def test_quickstart_code_runs(capsys: pytest.CaptureFixture[str]) -> None:
    namespace: dict[str, object] = {"__name__": "readme_quickstart"}
    exec(compile(readme_block("quickstart-code"), "README.md (quickstart)", "exec"), namespace)
    assert "offset at the end:" in capsys.readouterr().out
    result = namespace["result"]
    assert abs(result.y_phi[-1, 0] - 6.8) < 1e-3  # type: ignore[attr-defined]
    assert result.feasible.all()  # type: ignore[attr-defined]


def _check_links():  # type: ignore[no-untyped-def]
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import check_links
    finally:
        sys.path.pop(0)
    return check_links


def _site(tmp_path: Path, head: str, output: str) -> Path:
    (tmp_path / "index.html").write_text(
        f"<html><head>{head}</head><body id='top'><a href='#top'>top</a>"
        "<div class='sphx-glr-script-out highlight-none notranslate'><div class='highlight'>"
        f"<pre><span></span>{output}</pre></div></div></body></html>"
    )
    return tmp_path


def test_check_links_passes_a_clean_offline_site(tmp_path: Path) -> None:
    (tmp_path / "_static" / "mathjax").mkdir(parents=True)
    (tmp_path / "_static" / "mathjax" / "tex-chtml.js").write_text("")
    head = "<script src='_static/mathjax/tex-chtml.js'></script>"
    site = _site(tmp_path, head, "offset 1.2e-05 pH\nfeasible on every step: True\n")
    checked, problems = _check_links().check(site)
    assert checked == 2 and problems == []


@pytest.mark.parametrize(
    "head, output, why",
    [
        (
            "<script src='https://cdn.jsdelivr.net/npm/mathjax@3/es5/tex-mml-chtml.js'></script>",
            "ok\n",
            "another host",
        ),
        (
            "",
            "ltv_lstm_mpc: the compiled controller kernels are not in numba's cache yet: this "
            "controller runs the numpy reference kernels ... while a background process "
            "compiles them\n",
            "build machine",
        ),
        (
            "",
            "ltv_lstm_mpc: compiling the controller kernels (first run only, about 20-40 s on "
            "2 cores; cached on disk for the next runs)...\n",
            "build machine",
        ),
    ],
)
def test_check_links_flags_a_cdn_and_machine_dependent_output(
    tmp_path: Path, head: str, output: str, why: str
) -> None:
    _, problems = _check_links().check(_site(tmp_path, head, output))
    assert len(problems) == 1 and why in problems[0], problems


def test_own_plant_code_is_python() -> None:
    """Runs in tests/test_quadtank_readme.py after the user guide's training made its model;
    here: it parses and names what it promises."""
    code = readme_block("own-plant-code")
    ast.parse(code)
    assert "class TankPlant" in code and "LSTMModel.load(" in code
