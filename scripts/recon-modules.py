#!/usr/bin/env python3
"""The module import graph of crates/recon/src, drawn from the code, and the layout's rules checked.

    python3 scripts/recon-modules.py [--dot FILE]

Rooms: each method folder (`methods/<name>`), the registry (`methods/mod.rs`) and each top-level
module of the crate. An edge A → B is a `crate::B…` path (or `super::…` reaching B) in a
non-comment line of a file of A, test code excluded (`*tests.rs`, `tests/` folders and what follows
`#[cfg(test)]`). Checks: no room of the shared floor imports a method, the registry, the pipeline or
what stands on them; no method imports another; the room graph has no cycle. Exit status 1 when a
check fails.
"""
import pathlib, re, sys

SRC = pathlib.Path(__file__).resolve().parent.parent / "crates/recon/src"
FLOOR = {"algorithms", "device", "error", "evaluate", "gaussians", "init", "record", "setup"}
ABOVE = {"pipeline", "report", "decompose", "lib"}
METHODS = {"classic", "r2gs", "fourdsg", "naf"}


def room_of(rel: pathlib.PurePath) -> str:
    parts = rel.parts
    if parts[0] == "methods":
        return f"methods/{parts[1]}" if len(parts) > 2 else "methods"
    return parts[0].removesuffix(".rs")


def room_of_path(path: list[str]) -> str | None:
    if not path:
        return None
    if path[0] == "methods":
        return f"methods/{path[1]}" if len(path) > 1 and path[1] in METHODS else "methods"
    return path[0]


def module_path(rel: pathlib.PurePath) -> list[str]:
    parts = list(rel.with_suffix("").parts)
    if parts[-1] in ("mod", "lib"):
        parts.pop()
    return parts


def code_of(text: str) -> str:
    cut = re.search(r"#\[cfg\(test\)\]\s*(pub(\(crate\))?\s+)?mod\s+\w+\s*\{", text)
    text = text[: cut.start()] if cut else text
    return "\n".join(l for l in text.splitlines() if not l.lstrip().startswith("//"))


edges: dict[tuple[str, str], list[str]] = {}
for f in sorted(SRC.rglob("*.rs")):
    rel = f.relative_to(SRC)
    if f.name.endswith("tests.rs") or "tests" in rel.parts[:-1]:
        continue
    here = room_of(rel)
    me = module_path(rel)
    code = code_of(f.read_text())
    targets = [m.split("::") for m in re.findall(r"\bcrate::((?:[a-z_0-9]+::)*[a-z_0-9]+)", code)]
    for m in re.findall(r"\b((?:super::)+(?:[a-z_0-9]+::)*[a-z_0-9]*)", code):
        ups = m.count("super::")
        base = me[: max(len(me) - ups, 0)]
        rest = [p for p in m.split("::") if p and p != "super"]
        targets.append(base + rest)
    for t in targets:
        r = room_of_path(t)
        if r and r != here and r != "lib":
            edges.setdefault((here, r), []).append(str(rel))

rooms = sorted({a for a, _ in edges} | {b for _, b in edges})
bad = []
for (a, b), files in sorted(edges.items()):
    af = a in FLOOR
    bm = b.startswith("methods") or b in ABOVE
    if af and bm:
        bad.append(f"floor room {a} imports {b} ({', '.join(sorted(set(files)))})")
    if a.startswith("methods/") and b.startswith("methods/"):
        bad.append(f"method {a} imports method {b} ({', '.join(sorted(set(files)))})")

# cycles (Tarjan's strongly connected components)
graph = {r: sorted({b for (a, b) in edges if a == r}) for r in rooms}
index, low, stack, on, sccs, counter = {}, {}, [], set(), [], [0]
def strong(v):
    index[v] = low[v] = counter[0]; counter[0] += 1; stack.append(v); on.add(v)
    for w in graph.get(v, []):
        if w not in index:
            strong(w); low[v] = min(low[v], low[w])
        elif w in on:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop(); on.discard(w); comp.append(w)
            if w == v: break
        if len(comp) > 1: sccs.append(sorted(comp))
for r in rooms:
    if r not in index:
        strong(r)
bad += [f"cycle: {' ↔ '.join(c)}" for c in sccs]

def layer(r):
    return "floor" if r in FLOOR else "method" if r.startswith("methods/") else "registry" if r == "methods" else "above"
print(f"{len(rooms)} rooms, {len(edges)} edges")
for r in rooms:
    print(f"  [{layer(r):8}] {r:18} → {', '.join(graph.get(r, [])) or '–'}")
if "--dot" in sys.argv:
    out = pathlib.Path(sys.argv[sys.argv.index("--dot") + 1])
    lines = ["digraph recon {", "  rankdir=BT; node [shape=box];"]
    lines += [f'  "{a}" -> "{b}";' for (a, b) in sorted(edges)]
    out.write_text("\n".join(lines + ["}"]) + "\n")
    print(f"wrote {out}")
for b in bad:
    print("FAILS", b)
print("layout rules hold" if not bad else f"{len(bad)} rule(s) broken")
sys.exit(1 if bad else 0)
