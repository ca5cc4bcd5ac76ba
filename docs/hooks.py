"""mkdocs hook: adds the generated scene and CLI references (pipeline/reference.py) to every build,
so the manual's reference pages always match SCENE_SPEC and the argument parser."""
from __future__ import annotations

import sys
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline import reference  # noqa: E402


def on_files(files, config):
    for uri, make in ((reference.SCENE_PAGE, reference.scene_reference),
                      (reference.CLI_PAGE, reference.cli_reference)):
        old = files.get_file_from_path(uri)
        if old is not None:
            files.remove(old)
        files.append(File.generated(config, uri, content=make()))
    return files
