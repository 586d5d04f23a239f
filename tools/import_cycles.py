#!/usr/bin/env python3
"""Report import cycles between the source files of each crate.

For every crate ``crates/*/src``, this builds the graph "file A uses file B" and prints
each cycle (a strongly connected component of more than one file). Exits 1 if there
is any, else 0. Python 3 standard library only; run from the repository root:

    python3 tools/import_cycles.py [CRATES_DIR]

What counts as a use of another file
    ``crate::a::b::X``, ``super::X`` and ``self::a::X`` paths, in ``use`` trees
    (``use crate::{a, b::{X, Y}}``) or in code, resolved along the module tree
    (``mod a;`` declarations) to the deepest module that is a file. A name that a
    module brings in with ``use`` (the crate root's ``pub use a::X``, then
    ``crate::X``) is followed to the file it comes from; one from another crate is
    no edge.
What does not
    Comments, doc links and string literals. ``#[cfg(test)]`` modules, inline or in
    their own file (a test module using its parent via ``super::*`` is no cycle).
    A module's uses of its own submodules: a parent is made of its children (it
    declares, re-exports and calls them) and a child may use its parent's items, so
    only a child using its parent is an edge. Inline ``mod a { }`` blocks belong to
    their file; paths inside them are resolved from the inline module.
"""

import re
import sys
from pathlib import Path

TOKEN = re.compile(
    r'//[^\n]*|/\*.*?\*/|b?r(#*)".*?"\1|b?"(?:\\.|[^"\\])*"'
    r"|b?'(?:\\.|[^'\\\n])'|(?P<keep>[\s\S])",
    re.S,
)
MOD_DECL = re.compile(r"(#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*)?(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*([;{])")
USE = re.compile(r"\buse\s+([^;]*);")
PATH = re.compile(r"(?<![\w:])(?:crate|self|super)(?:\s*::\s*\w+)+")


def blank(text):
    return re.sub(r"[^\n]", " ", text)


def strip(src):
    """Blanks comments and literals, keeping newlines."""
    out = []
    for m in TOKEN.finditer(src):
        text = m.group(0)
        out.append(text if m.group("keep") else blank(text))
    return "".join(out)


def block_end(code, open_brace):
    """Index just past the brace matching the one at `open_brace`."""
    depth = 0
    for i in range(open_brace, len(code)):
        depth += {"{": 1, "}": -1}.get(code[i], 0)
        if depth == 0:
            return i + 1
    return len(code)


def use_paths(tree, prefix=()):
    """Expands a use tree (`a::{self, b, c::d as e}`) into (path, name bound) pairs."""
    head, brace, rest = tree.strip().partition("{")
    parts = prefix + tuple(p.strip() for p in head.split("::") if p.strip())
    if brace:
        out, depth, item = [], 0, ""
        for ch in rest.rsplit("}", 1)[0] + ",":
            depth += {"{": 1, "}": -1}.get(ch, 0)
            if ch == "," and depth == 0:
                out += use_paths(item, parts) if item.strip() else []
                item = ""
            else:
                item += ch
        return out
    *path, last = parts
    words = last.split()  # `name` or `name as alias`
    if words[0] == "*":
        return [(tuple(path), None)]
    if words[0] == "self":
        return [(tuple(path), path[-1] if words[-1] == "self" else words[-1])]
    return [(tuple(path) + (words[0],), words[-1])]


class Crate:
    """The module tree of one crate and its files' stripped sources."""

    def __init__(self, src):
        self.files = {}  # module path (tuple of names) -> file, for modules that are files
        self.mods = {}  # file -> module path
        self.code = {}  # file -> stripped source with test modules blanked
        self.inline = {}  # file -> [(start, end, name)] of its inline modules
        self.alias_cache = {}
        self.load((), src / "lib.rs" if (src / "lib.rs").exists() else src / "main.rs", src)

    def load(self, mod, file, child_dir):
        code = strip(file.read_text(encoding="utf-8"))
        for m in reversed(list(MOD_DECL.finditer(code))):
            if m.group(1) and m.group(3) == "{":
                end = block_end(code, m.end() - 1)
                code = code[: m.start()] + blank(code[m.start() : end]) + code[end:]
        self.files[mod], self.mods[file] = file, mod
        self.code[file], self.inline[file] = code, []
        for m in MOD_DECL.finditer(code):
            test, name, kind = m.groups()
            if kind == "{":
                self.inline[file].append((m.end() - 1, block_end(code, m.end() - 1), name))
            elif not test:
                for child in (child_dir / f"{name}.rs", child_dir / name / "mod.rs"):
                    if child.exists():
                        self.load(mod + (name,), child, child_dir / name)
                        break

    def module_at(self, mod, file, pos):
        """The module of the code at `pos` in `file`, the file's module `mod` or inside it."""
        return mod + tuple(name for start, end, name in self.inline[file] if start < pos < end)

    def uses(self, mod, file):
        """(module, path) of every `crate::`, `self::` and `super::` path in `file`."""
        code = self.code[file]
        found = [(m.start(), p) for m in USE.finditer(code) for p, _ in use_paths(m.group(1))]
        for m in PATH.finditer(code):
            found.append((m.start(), tuple(re.split(r"\s*::\s*", m.group(0)))))
        for pos, path in found:
            if path[0] in ("crate", "self", "super"):
                yield self.module_at(mod, file, pos), path

    def aliases(self, mod):
        """Names bound by `use` at the top of module `mod` -> absolute paths (None: external)."""
        if mod not in self.alias_cache:
            file, out = self.files[mod], {}
            for m in USE.finditer(self.code[file]):
                if self.module_at(mod, file, m.start()) == mod:
                    for path, name in use_paths(m.group(1)):
                        if name:
                            out[name] = self.absolute(mod, path)
            self.alias_cache[mod] = out
        return self.alias_cache[mod]

    def absolute(self, mod, path):
        """`path` as seen from module `mod`, from the crate root; None if in another crate."""
        if path[0] == "crate":
            return path[1:]
        if path[0] not in ("self", "super"):
            return mod + path if mod + path[:1] in self.files else None
        for i, name in enumerate(path):
            if name == "super":
                if not mod:
                    return None
                mod = mod[:-1]
            elif name != "self":
                return mod + path[i:]
        return mod

    def target(self, path, hops=0):
        """The file an absolute path lands in, following re-exports; None if external."""
        mod = ()
        for i, name in enumerate(path):
            if mod + (name,) in self.files:
                mod += (name,)
                continue
            aliases = self.aliases(mod)
            if name in aliases and hops < 10:
                alias = aliases[name]
                return alias and self.target(alias + path[i + 1 :], hops + 1)
            break
        return self.files[mod]

    def graph(self):
        """file -> set of the other files it uses."""
        graph = {}
        for mod, file in self.files.items():
            graph[file] = set()
            for here, path in self.uses(mod, file):
                absolute = self.absolute(here, path)
                to = None if absolute is None else self.target(absolute)
                if to is not None and self.mods[to][: len(mod)] != mod:  # not itself nor a child
                    graph[file].add(to)
        return graph


def cycles(graph):
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while not comp or comp[-1] != v:
                comp.append(stack.pop())
                on.discard(comp[-1])
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def main():
    crates = Path(sys.argv[1] if len(sys.argv) > 1 else "crates")
    found = 0
    for src in sorted(crates.glob("*/src")):
        graph = Crate(src).graph()
        for comp in cycles(graph):
            found += 1
            names = {f: str(f.relative_to(src)) for f in comp}
            print(f"{src.parent.name}: cycle between {', '.join(names[f] for f in comp)}")
            for f in comp:
                uses = sorted(names[t] for t in graph[f] if t in names)
                print(f"    {names[f]} uses {', '.join(uses)}")
    print(f"{found} import cycle(s)" if found else "no import cycles")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
