"""Every repository path that the README, the docs, the results READMEs and the study files name exists.

A path is a token in inline code (`...`), the target of a markdown link, or (in a study file) an argument's value,
the record folder, or a path in a comment. Not checked: URLs, absolute paths (/tmp/...), paths under folders a run
writes and git ignores (runs/, demos/, ...), globs and brace expansions, placeholders (<run>, RUN_DIR, $ROOT),
outputs of the commands that name them (--out X, --json X, > X, hydra.run.dir=X) and any path the same file writes
with such an option. A path resolves from the repository root or from the document's folder or one above it,
so a results README may name its own files relatively (`run_files/drs_s0/`); a path whose first part
exists nowhere there is prose (`fp32/bf16`), not checked."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
IGNORED_ROOTS = ("runs/", "demos/", "outputs/", "multirun/", ".venv/", "build/", "dist/", "videos/")
OUTPUT_OPTIONS = ("--out", "--json", ">", ">>", "--video")
OUTPUT_KEYS = ("hydra.run.dir", "out", "report.out", "hydra.sweep.dir")
FILE_NAMES = ("README.md", "CHANGELOG.md", "LICENSE", "pyproject.toml", "mkdocs.yml", "MANIFEST.in")
SUFFIXES = (".md", ".py", ".yaml", ".yml", ".sh", ".pt", ".json", ".csv", ".png", ".txt", ".toml", ".demos", ".log")
ALL_CAPS_FILES = {"COMMAND", "NOTE", "README", "LICENSE", "CHANGELOG", "COMPLETE", "MANIFEST"}


def _top_level() -> set[str]:
    return {p.name for p in REPO.iterdir() if not p.name.startswith(".")}


def _looks_like_path(token: str) -> bool:
    """A token that names a file or folder of the repository (not prose like fp32/bf16, not a placeholder)."""
    if (
        not token
        or "://" in token
        or token.startswith(("/", "~", "$", "-", ".venv", "#"))
        or token.startswith(IGNORED_ROOTS)
    ):
        return False
    if any(c in token for c in "*?[]{}<>$|,;:()'\"\\=") or "..." in token or "…" in token:
        return False
    parts = [p for p in token.split("/") if p not in ("", ".")]
    if not parts or any(re.fullmatch(r"[A-Z][A-Z0-9_]*", p) and p not in ALL_CAPS_FILES for p in parts):
        return False  # RUN_DIR, OUT/..., R/reward.pt: placeholders
    if "/" not in token.rstrip("/"):
        return token in FILE_NAMES  # a bare file name: only the repository's own top-level files
    return True


def _candidates(tokens: list[str]) -> tuple[list[str], set[str]]:
    """(paths to check, outputs): a command's output path (after --out, as hydra.run.dir=...) may not exist yet."""
    paths, outputs = [], set()
    for i, raw in enumerate(tokens):
        tok = raw.lstrip("(\"'").rstrip(".,;:)'\"")
        key, eq, value = tok.partition("=")
        value = value if eq else tok
        if not _looks_like_path(value.lstrip("+")):
            continue
        value = value.split("#")[0]
        if (eq and key.lstrip("+") in OUTPUT_KEYS) or (i > 0 and tokens[i - 1] in OUTPUT_OPTIONS):
            outputs.add(value.rstrip("/"))
        else:
            paths.append(value)
    return paths, outputs


def paths_in_markdown(text: str) -> tuple[list[str], set[str]]:
    """Paths a markdown file names in inline code and links (fenced code blocks are commands: their outputs only)."""
    paths, outputs = [], set()
    fenced = re.findall(r"^```.*?^```", text, flags=re.S | re.M)
    for block in fenced:
        outputs |= _candidates(block.split())[1]
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    for span in re.findall(r"(?<!`)`([^`\n]+)`(?!`)", prose):
        p, o = _candidates(span.split())
        paths += p
        outputs |= o
    for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", prose):
        target = target.split("#")[0]
        if target and _looks_like_path(target) or target in FILE_NAMES:
            paths.append(target)
    return paths, outputs


def paths_in_study(text: str) -> tuple[list[str], set[str]]:
    """Paths a study file names: its record, every run's (and the common) argument values, paths in its comments."""
    spec = yaml.safe_load(text) or {}
    tokens = [f"record={spec['record']}"] if spec.get("record") else []
    tokens += [str(a) for a in spec.get("common") or []]
    tokens += [str(a) for r in spec.get("runs") or [] for a in r.get("args") or []]
    tokens += [f"{k}={v}" for k, vs in (spec.get("grid") or {}).items() for v in (vs if isinstance(vs, list) else [vs])]
    paths, outputs = _candidates(tokens)
    comments = " ".join(line.split("#", 1)[1] for line in text.splitlines() if "#" in line)
    p, o = _candidates(comments.split())
    return paths + p, outputs | o


def _exists_in_repo(path: Path) -> bool:
    """``path`` exists and lies inside the repository: a sibling checkout (../ft-wt) exists only on some machines."""
    resolved = path.resolve()
    return resolved.exists() and (resolved == REPO or REPO in resolved.parents)


def missing_paths(doc: Path, text: str | None = None) -> list[str]:
    """The paths ``doc`` names that do not exist (``text`` instead of the file's own)."""
    text = doc.read_text() if text is None else text
    paths, outputs = (paths_in_study if doc.suffix in (".yaml", ".yml") else paths_in_markdown)(text)
    here = doc.resolve().parent
    bases = list(dict.fromkeys([here, *[p for p in here.parents if p == REPO or REPO in p.parents], REPO]))
    missing = []
    for p in dict.fromkeys(paths):
        if p.rstrip("/") in outputs:
            continue
        first = p.split("/")[0]
        if not any((b / first).exists() for b in bases):
            continue  # prose with a slash (D_k/dense, fp32/bf16): its first part names nothing here
        if not any(_exists_in_repo(b / p) for b in bases):
            missing.append(p)
    return missing


def _report(docs: list[Path]) -> str:
    lines = [f"{d.relative_to(REPO)}: {p}" for d in docs for p in missing_paths(d)]
    return "\n".join(lines)


def results_docs() -> list[Path]:
    return sorted([*(REPO / "results").rglob("README.md"), *(REPO / "results").rglob("study.yaml")])


def test_the_results_readmes_and_study_files_name_paths_that_exist():
    docs = results_docs()
    assert len(docs) > 20
    assert not _report(docs), "paths that do not exist:\n" + _report(docs)


def test_the_readme_and_docs_name_paths_that_exist():
    docs = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    assert not _report(docs), "paths that do not exist:\n" + _report(docs)


def test_the_extractor_catches_a_broken_path_and_ignores_what_is_no_path(tmp_path):
    doc = REPO / "results" / "README.md"  # resolved from results/ and the repository root
    text = """See `results/precision/study.yaml`, `bench/README.md` and [the record](precision/README.md#top).
Broken: `results/precision/no_such_study.yaml`, [gone](results/nowhere/), `drs-eval results/reuse/turn_valve/run_files/x_s9 --split test`.
Not paths: `runs/maze/study/learn-s0/reward.pt`, `<run>/reward.pt`, `RUN_DIR/checkpoints/policy.pt`, `fp32/bf16`,
`results/**/study.yaml`, `seed-{0,1}`, `D_k/dense`, [site](https://example.org/a/b), `/tmp/x/y.pt`, `$ROOT/learn-s0`,
`drs-probe --reward R.pt --out probe/`, `hydra.run.dir=results/new_run`, `--json results/bench/new.json`.
```bash
drs-demos --out results/generated/planner.demos
```
and `results/generated/planner.demos` is written by the command above."""
    text += "\nA sibling checkout counts as missing, whether or not this machine has one: `../no_such_checkout`."
    assert sorted(missing_paths(doc, text)) == [
        "../no_such_checkout",
        "results/nowhere/",
        "results/precision/no_such_study.yaml",
        "results/reuse/turn_valve/run_files/x_s9",
    ]
    study = tmp_path / "study.yaml"
    study.write_text(
        yaml.safe_dump(
            {
                "root": "runs/x",
                "record": "results/no_record",
                "common": ["env=pick_cube", "demos.path=results/reuse/turn_valve/demos_dense_policy_levels024.demos"],
                "runs": [
                    {
                        "name": "a",
                        "args": ["reward.checkpoint=results/gone/reward.pt", "init_from=<policy:b>", "seed=0"],
                    }
                ],
            }
        )
        + "# made by: drs-demos --out results/made.demos; see results/missing/README.md\n"
    )
    assert missing_paths(study) == ["results/no_record", "results/gone/reward.pt", "results/missing/README.md"]


def test_a_path_outside_the_repository_is_missing_even_where_this_machine_has_it(tmp_path, monkeypatch):
    """The check gives the same verdict on every machine: a sibling worktree that exists here does not count."""
    import sys

    repo, sibling = tmp_path / "repo", tmp_path / "ft-wt"
    (repo / "results").mkdir(parents=True)
    sibling.mkdir()
    (repo / "results" / "notes.md").write_text("x")
    monkeypatch.setattr(sys.modules[__name__], "REPO", repo)
    doc = repo / "results" / "README.md"
    assert missing_paths(doc, "Runs in `../ft-wt`; see `results/notes.md`.") == ["../ft-wt"]


def _drs_imports(script: Path) -> list[tuple[str, str | None]]:
    """The (module, name) pairs a script imports from drs_torchrl (name None: ``import drs_torchrl.x``)."""
    import ast

    out = []
    for node in ast.walk(ast.parse(script.read_text())):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("drs_torchrl"):
            out += [(node.module, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names if a.name.startswith("drs_torchrl")]
    return out


def _missing_imports(scripts: list[Path], root: Path = REPO) -> list[str]:
    import importlib

    bad = []
    for script in scripts:
        for module, name in _drs_imports(script):
            try:
                mod = importlib.import_module(module)
            except ImportError as e:
                bad.append(f"{script.relative_to(root)}: {module} ({e})")
                continue
            if name is not None and name != "*" and not hasattr(mod, name):
                try:  # a submodule imported by name
                    importlib.import_module(f"{module}.{name}")
                except ImportError:
                    bad.append(f"{script.relative_to(root)}: {module}.{name}")
    return bad


def test_the_results_scripts_import_only_what_the_package_has(tmp_path):
    """The committed analysis scripts (results/**/*.py) are run on their records long after they were written: every
    name they import from drs_torchrl must still exist (a refactor that removes one must update them)."""
    scripts = sorted((REPO / "results").rglob("*.py"))
    assert len(scripts) > 10 and sum(len(_drs_imports(s)) for s in scripts) > 10
    assert not _missing_imports(scripts), "\n".join(_missing_imports(scripts))
    broken = tmp_path / "old.py"  # the check itself: a name the package no longer has
    broken.write_text("from drs_torchrl.apps.maze import make_env, make_qnet\n")
    assert _missing_imports([broken], tmp_path) == ["old.py: drs_torchrl.apps.maze.make_qnet"]
