"""mkdocs hook: generate the CLI and config reference at build time, and mount the figures the pages show.

* ``reference/cli.md``: every console script of ``pyproject.toml`` ``[project.scripts]`` with its ``--help``.
  argparse scripts are asked for their parser without running anything (``docs/hooks/cli_help.py``, one
  process); Hydra apps print Hydra's own ``--help`` (config groups and the composed config); a script with
  neither gets its entry point's docstring.
* ``reference/config.md``: every YAML file of ``conf/``, group by group, verbatim.
* ``results/**/*.png`` that a page references: copied into the site at the same path, so that a page can show
  ``results/quickstart/seed0/quickstart.png`` from the committed studies.

It also points ``pymdownx.snippets`` at the repository root, so that pages can include committed records
(``results/reuse/CLAIMS.md``, ``results/bad_inputs/README.md``) whatever directory mkdocs runs from.

A script whose help cannot be produced, a missing ``conf/`` or a referenced figure that does not exist is a
warning, which ``mkdocs build --strict`` turns into a failed build.
"""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.reference")

HERE = Path(__file__).resolve().parent
FIGURE_RE = re.compile(r"(?<![\w/])(results/[\w./-]+\.(?:png|svg|jpg))")


def _root(config) -> Path:
    return Path(config["config_file_path"]).resolve().parent


def _scripts(root: Path) -> dict[str, str]:
    text = (root / "pyproject.toml").read_text()
    try:
        import tomllib

        return dict(tomllib.loads(text)["project"]["scripts"])
    except ImportError:  # Python 3.10: the table is simple enough to read by hand
        block = text.split("[project.scripts]", 1)[1].split("\n[", 1)[0]
        return dict(re.findall(r'^\s*([\w-]+)\s*=\s*"([^"]+)"', block, re.M))


def _conf_dir(root: Path) -> Path | None:
    for cand in (root / "conf", root / "src" / "drs_torchrl" / "conf"):
        if (cand / "learn.yaml").is_file():
            return cand
    return None


def _cli_page(root: Path) -> str:
    scripts = _scripts(root)
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONPATH=str(root / "src"))
    try:
        proc = subprocess.run(
            [sys.executable, str(HERE / "cli_help.py"), json.dumps(scripts)],
            cwd=root,
            env=env,
            capture_output=True,
            text=True,
            timeout=240,
        )
        helps = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout.strip() else {}
        if proc.returncode != 0 and not helps:
            log.warning("cli reference: cli_help.py failed (%s): %s", proc.returncode, proc.stderr[-2000:])
    except (subprocess.TimeoutExpired, json.JSONDecodeError, IndexError) as exc:
        log.warning("cli reference: could not collect --help: %s", exc)
        helps = {}
    lines = [
        "# Command-line reference",
        "",
        "Generated at build time from `pyproject.toml` (`[project.scripts]`) and each script's `--help`",
        "(`docs/hooks/reference.py`). The Hydra apps take `group=option` and `key=value` overrides; every group",
        "and option is on the [config reference](config.md) page.",
        "",
        "| script | entry point | kind |",
        "|---|---|---|",
    ]
    for name, target in scripts.items():
        kind = helps.get(name, {}).get("kind", "?")
        lines.append(f"| [`{name}`](#{name}) | `{target}` | {kind} |")
    lines.append("")
    for name, target in scripts.items():
        info = helps.get(name)
        if not info or not info.get("help"):
            log.warning(
                "cli reference: no help for %s (%s): %s", name, target, (info or {}).get("error", "not collected")
            )
            continue
        text = re.sub(r"^\S+ is powered by Hydra\.", f"{name} is powered by Hydra.", info["help"].strip("\n"))
        lines += [f"## {name}", "", f"`{target}`: {info['kind']}.", "", "```text", text.rstrip(), "```", ""]
    return "\n".join(lines)


def _config_page(root: Path) -> str:
    conf = _conf_dir(root)
    if conf is None:
        log.warning("config reference: no conf/ directory with learn.yaml found")
        return "# Config reference\n\nNo `conf/` directory was found.\n"
    rel = conf.relative_to(root).as_posix()
    lines = [
        "# Config reference",
        "",
        f"Every file of `{rel}/`, verbatim, generated at build time (`docs/hooks/reference.py`). The top-level files",
        "are the apps' primary configs (`drs-learn` reads `learn.yaml`, `drs-reuse` `reuse.yaml`, `drs-maze`",
        "`maze.yaml`, `drs-quickstart` `quickstart.yaml`); each folder is a config group, chosen with",
        "`group=option` (`env=turn_valve`, `reward=semi_sparse`) or added with `+group=option` (`+ablation=placed_5cm`).",
        "Any key can be overridden on the command line (`algo.batch_size=512`); `+key=value` adds a key only where",
        "keys are free-form (`+env.variant_overrides.goal_thresh=0.05`, an argument of a `_target_`): a key that",
        "nothing reads is refused with the setting meant (`apps/overrides.py`).",
        "",
        "## Primary configs",
        "",
    ]
    for f in sorted(conf.glob("*.yaml")):
        lines += [f"### {f.name}", "", "```yaml", f.read_text().rstrip(), "```", ""]
    for group in sorted(p for p in conf.iterdir() if p.is_dir()):
        options = sorted(group.glob("*.yaml"))
        if not options:
            continue
        lines += [
            f"## {group.name}",
            "",
            "Options: " + ", ".join(f"`{group.name}={o.stem}`" for o in options) + ".",
            "",
        ]
        for f in options:
            lines += [f"### {group.name}={f.stem}", "", "```yaml", f.read_text().rstrip(), "```", ""]
    return "\n".join(lines)


def on_config(config):
    # snippets (`--8<-- "results/reuse/CLAIMS.md"`) are read from the repository root, whatever the cwd
    snippets = config["mdx_configs"].get("pymdownx.snippets")
    if snippets is not None:
        snippets["base_path"] = [str(_root(config))]
    return config


def on_files(files, config):
    root = _root(config)
    for uri, content in (("reference/cli.md", _cli_page(root)), ("reference/config.md", _config_page(root))):
        old = files.get_file_from_path(uri)
        if old is not None:
            files.remove(old)
        files.append(File.generated(config, uri, content=content))
    # figures of the committed studies that a page shows
    wanted = set()
    for f in files.documentation_pages():
        if f.abs_src_path:
            wanted.update(FIGURE_RE.findall(Path(f.abs_src_path).read_text()))
    for uri in sorted(wanted):
        src = root / uri
        if not src.is_file():
            log.warning("a page shows %s, which is not in the repository", uri)
            continue
        if files.get_file_from_path(uri) is None:
            files.append(File.generated(config, uri, abs_src_path=str(src)))
    return files
