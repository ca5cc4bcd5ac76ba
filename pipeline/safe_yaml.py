"""YAML for scene and sweep files that cannot hang or crash the pipeline: the file is checked to be a
regular file of bounded size before it is read, and the composed node tree is checked before anything
is built from it: nesting depth bounded, alias expansion bounded (a recursive alias refused), keys only
plain scalars. Every problem is one line naming the file, line and column (raised as `exc`)."""
from __future__ import annotations

import os
import stat
from pathlib import Path

import yaml

MAX_BYTES = 4 * 1024 * 1024      # a scene or sweep file is a few kB; 4 MB is far beyond any real one
MAX_DEPTH = 64                   # the deepest real scene is ~6 levels
MAX_NODES = 200_000              # values after alias expansion (a 1,000-job sweep file is ~10,000)


def check_regular_file(path: Path, what: str, exc, *, max_bytes: int | None = None) -> None:
    """Raise exc(one line) unless `path` is an existing regular file (not a folder, FIFO, device or
    socket) of at most `max_bytes`. Uses stat, never open, so a FIFO cannot block."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise exc(f"{path}: {what} not found") from None
    except OSError as e:
        raise exc(f"{path}: cannot read {what} ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise exc(f"{path}: is a folder, expected a {what}")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else
                "a character device" if stat.S_ISCHR(st.st_mode) else
                "a block device" if stat.S_ISBLK(st.st_mode) else
                "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise exc(f"{path}: is {kind}, expected a {what} (a regular file)")
    if max_bytes is not None and st.st_size > max_bytes:
        raise exc(f"{path}: the {what} is {st.st_size:,} bytes, more than the limit of {max_bytes:,} "
                  f"(expected a small text file)")


def read_text_file(path: Path, what: str, exc, *, max_bytes: int = MAX_BYTES) -> str:
    """The text of a regular UTF-8 file of at most `max_bytes`, or exc(one line)."""
    check_regular_file(path, what, exc, max_bytes=max_bytes)
    try:
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise exc(f"{path}: the {what} is more than {max_bytes:,} bytes (expected a small text file)")
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise exc(f"{path}: cannot read {what}: not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise exc(f"{path}: cannot read {what} ({e.strerror or e})") from None


def _at(source: str, node) -> str:
    m = node.start_mark
    return f"{source}:{m.line + 1}:{m.column + 1}"


def check_node(root, source: str, exc) -> None:
    """Refuse a composed tree that is too deep, expands past MAX_NODES values, refers to itself, or
    has a key that is not a plain scalar. The walk stops at the first problem: bounded time."""
    count = 0
    on_path: set = set()
    stack = [(root, 0, False)]
    while stack:
        node, depth, leaving = stack.pop()
        if leaving:
            on_path.discard(id(node))
            continue
        count += 1
        if count > MAX_NODES:
            raise exc(f"{_at(source, node)}: YAML expands to more than {MAX_NODES:,} values (aliases "
                      f"'*name' repeating anchors '&name'?); expected a scene-sized file")
        if depth > MAX_DEPTH:
            raise exc(f"{_at(source, node)}: YAML nested more than {MAX_DEPTH} levels deep; expected "
                      f"a scene's few levels of mappings and lists")
        if isinstance(node, yaml.ScalarNode):
            continue
        if id(node) in on_path:
            raise exc(f"{_at(source, node)}: a YAML alias refers to a mapping or list that contains it "
                      f"(a recursive alias); expected plain values")
        on_path.add(id(node))
        stack.append((node, depth, True))
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if not isinstance(k, yaml.ScalarNode):
                    kind = "mapping" if isinstance(k, yaml.MappingNode) else "list"
                    raise exc(f"{_at(source, k)}: a YAML key is a {kind} ('? ' complex key); expected a "
                              f"plain name such as 'garments'")
                stack.append((v, depth + 1, False))
        else:
            for v in node.value:
                stack.append((v, depth + 1, False))


def _depth_precheck(text: str, source: str, exc) -> None:
    """Refuse bracket nesting deeper than MAX_DEPTH before the recursive composer sees it."""
    depth = deepest = 0
    for line_no, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("#"):
            continue
        for ch in line:
            if ch in "[{":
                depth += 1
                if depth > MAX_DEPTH:
                    raise exc(f"{source}:{line_no}: YAML nested more than {MAX_DEPTH} levels deep; "
                              f"expected a scene's few levels of mappings and lists")
            elif ch in "]}":
                depth = max(0, depth - 1)
            elif ch in "'\"#":
                break   # a quoted string or comment: brackets after it are not nesting (coarse, safe)
        deepest = max(deepest, depth)


def compose_checked(text: str, source: str, exc):
    """The checked node tree of `text` (None for an empty document)."""
    _depth_precheck(text, source, exc)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except RecursionError:
        raise exc(f"{source}: YAML nested too deep; expected a scene's few levels of mappings and lists") from None
    if node is not None:
        check_node(node, source, exc)
    return node


def load_checked(text: str, source: str, exc, loader=yaml.SafeLoader):
    """(data, node): `text` parsed with `loader` after compose_checked passed. yaml errors propagate."""
    node = compose_checked(text, source, exc)
    try:
        data = yaml.load(text, Loader=loader)
    except RecursionError:
        raise exc(f"{source}: YAML nested too deep; expected a scene's few levels of mappings and lists") from None
    except TypeError as e:   # an unhashable key that slipped through (merge of odd values)
        raise exc(f"{source}: YAML key that is not a plain name ({e})") from None
    return data, node
