#!/usr/bin/env bash
# A view of the main checkout's .venv for a study worktree pinned to an older commit: the same interpreter and
# packages (lib/ is a link), but console scripts generated from the *worktree's* pyproject.toml that import the
# *worktree's* src/ (put first on sys.path), so that the pinned code runs whatever the main checkout becomes. (A
# process the scripts start with `python -m` or a bare `python` still needs PYTHONPATH=$PWD/src.) Usage, from the worktree:
#   bash results/recipe/venv_view.sh ../main/.venv ../study-venv && rm -f .venv && ln -s ../study-venv .venv
set -euo pipefail
MAIN=$(realpath "${1:?usage: venv_view.sh MAIN_VENV VIEW_DIR}"); VIEW=$(realpath -m "${2:?usage: venv_view.sh MAIN_VENV VIEW_DIR}")
mkdir -p "$VIEW/bin"
cp "$MAIN/pyvenv.cfg" "$VIEW/"
ln -sfn "$MAIN/lib" "$VIEW/lib"; ln -sfn lib "$VIEW/lib64"
ln -sfn "$(readlink -f "$MAIN/bin/python3")" "$VIEW/bin/python3"; ln -sfn python3 "$VIEW/bin/python"
for f in "$MAIN"/bin/*; do  # every other program of the venv (ruff, mkdocs, pytest, ...) as it is
  case "$(basename "$f")" in drs-*|python*|activate*|Activate*) ;; *) ln -sfn "$f" "$VIEW/bin/$(basename "$f")";; esac
done
"$VIEW/bin/python3" - "$VIEW" <<'PY'
import sys, tomllib
from pathlib import Path
view = Path(sys.argv[1])
for name, target in tomllib.loads(Path("pyproject.toml").read_text())["project"]["scripts"].items():
    module, func = target.split(":")
    script = view / "bin" / name
    # the __main__ guard as pip writes it: collectors that spawn worker processes re-import this file
    # the worktree's src/ first on the path: the view's packages hold an editable install of the *main* checkout,
    # which would otherwise shadow the pinned code (PYTHONPATH=$PWD/src did this by hand, and was easy to forget)
    src = Path.cwd().resolve() / "src"
    script.write_text(
        f"#!{view}/bin/python3\nimport sys\nsys.path.insert(0, {str(src)!r})\nfrom {module} import {func}\n\n"
        f"if __name__ == '__main__':\n    sys.exit({func}())\n"
    )
    script.chmod(0o755)
    print(name, "->", target)
PY
