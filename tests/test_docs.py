"""The manual: its generated references cover every scene key and every CLI subcommand, its pages
exist, the README stays short and keeps the two commands CI runs, and (where mkdocs is installed)
`mkdocs build --strict` passes."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import reference
from pipeline.scene import OUTPUT_FIELDS, SCENE_SPEC

ROOT = Path(__file__).resolve().parent.parent


def _all_key_paths() -> list[str]:
    """Every key of SCENE_SPEC as the reference's table names it (list items as `garments[].key`)."""
    out: list[str] = []

    def walk(fields, prefix):
        for k, f in fields.items():
            out.append(prefix + k)
            if f.kind == "section":
                walk(f.fields, prefix + k + ".")
            if f.kind == "list" and f.item is not None and f.item.kind == "union":
                for sub in f.item.variants.values():
                    walk(sub, f"{prefix}{k}[].")
    walk(SCENE_SPEC, "")
    walk(OUTPUT_FIELDS, "output.")
    return out


def test_scene_reference_has_every_key():
    page = reference.scene_reference()
    missing = [k for k in _all_key_paths() if f"| `{k}` |" not in page]
    assert not missing, f"scene keys missing from the generated reference: {missing}"
    for t in SCENE_SPEC["garments"].item.variants:
        assert f"`type: {t}`" in page
    for t in SCENE_SPEC["obstacles"].item.variants:
        assert f"`type: {t}`" in page


def test_scene_reference_rows_have_type_default_range_meaning():
    for line in reference.scene_reference().splitlines():
        if line.startswith("| `"):
            cells = [c for c in re.split(r"(?<!\\)\|", line)[1:-1]]
            assert len(cells) == 5, line
            assert all(c.strip() for c in cells[:4]), line


def test_cli_reference_has_every_subcommand_and_option():
    from pipeline.cli import build_parser
    page = reference.cli_reference()
    subs = reference.subcommands()
    assert {"run", "validate", "bench", "matrix", "export", "sweep", "inspect", "snapshot"} <= set(subs)
    for name in subs:
        assert f"\n## {name}\n" in page, name
    for name, _, sp in reference._subparsers(build_parser()):
        for a in sp._actions:
            for opt in a.option_strings:
                if a.help != "==SUPPRESS==" and opt not in ("-h", "--help"):
                    assert opt in page, (name, opt)


def test_nav_pages_exist():
    nav = re.findall(r":\s*([\w/]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    generated = {reference.SCENE_PAGE, reference.CLI_PAGE}
    assert len(nav) >= 15
    for page in nav:
        assert page in generated or (ROOT / "docs" / page).is_file(), page


def test_readme_short_and_keeps_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    assert 'pip install -e ".[test]" && python -m pytest' in text
    assert "python -m pipeline run scenes/default.yaml" in text
    assert "docs/default_f045_viewer.png" in text
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'pip install -e ".[test]" && python -m pytest' in ci
    assert "mkdocs build --strict" in ci


def test_user_guide_reads_as_a_manual_not_lab_notes():
    """No dated diary in the user docs: no dates, branch names or issue numbers in the guide pages."""
    for page in sorted((ROOT / "docs" / "guide").glob("*.md")) + [ROOT / "docs" / "index.md",
                                                                  ROOT / "docs" / "troubleshooting.md"]:
        text = page.read_text()
        assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), page.name
        assert not re.search(r"\bissue \d+\b|\bbranch `", text), page.name


@pytest.mark.skipif(shutil.which("mkdocs") is None and not Path(sys.executable).with_name("mkdocs").exists(),
                    reason="mkdocs is not installed (the 'docs' extra: pip install -e '.[docs]')")
def test_mkdocs_build_strict(tmp_path):
    exe = shutil.which("mkdocs") or str(Path(sys.executable).with_name("mkdocs"))
    r = subprocess.run([exe, "build", "--strict", "-q", "-d", str(tmp_path / "site")], cwd=ROOT,
                       capture_output=True, text=True, timeout=300, env={**__import__("os").environ,
                                                                          "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "site" / "reference" / "scene" / "index.html").is_file()
