"""YAML that cannot hang or crash the pipeline (scene and sweep files, GarmentCode body files): read
with stages.input_files.read_text_file (a regular file of bounded size), the composed node tree is
checked before anything is built from it: nesting depth bounded, alias expansion bounded (a recursive alias refused), keys only
plain scalars. Every problem is one line naming the file, line and column (raised as `exc`)."""
from __future__ import annotations

import yaml

MAX_DEPTH = 64                   # the deepest real scene is ~6 levels
MAX_NODES = 200_000              # values after alias expansion (a 1,000-job sweep file is ~10,000)


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
