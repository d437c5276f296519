#!/usr/bin/env bash
# Build the documentation site with warnings as errors.
#
#   bash docs/build.sh                   # site in out/site inside the checkout (git-ignored)
#   SITE_DIR=/some/where bash docs/build.sh
#
# The docs tools live in their own virtual environment (.venv-docs), not in .venv.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

PY="${PY:-python3}"
DOCS_VENV="$ROOT/.venv-docs"
SITE_DIR="${SITE_DIR:-$ROOT/out/site}"
export NO_MKDOCS_2_WARNING=1  # silence Material's end-of-life banner (not a build warning)

# 1. Docs tools (installed once; delete .venv-docs to reinstall).
if [[ ! -x "$DOCS_VENV/bin/mkdocs" ]] || ! "$DOCS_VENV/bin/python" -c "import mkdocstrings_handlers.python, material, mdx_breakless_lists" 2>/dev/null; then
    "$PY" -m venv "$DOCS_VENV"
    "$DOCS_VENV/bin/python" -m pip install -q mkdocs-material "mkdocstrings[python]" mdx-breakless-lists
fi

# 2. Regenerate the generated pages from the code: the CLI reference from the argparse parser,
#    the API reference pages (one block per public module), the config tables (fit config, capture header, emulator options, scene files) from their
#    typed declarations. The scripts put src/ on sys.path, so any Python >= 3.11 with the
#    project's dependencies works; prefer the project's .venv.
if [[ -x "$ROOT/.venv/bin/python" ]]; then
    CLI_PY="$ROOT/.venv/bin/python"
else
    CLI_PY="$PY"
fi
"$CLI_PY" docs/gen_cli.py
"$CLI_PY" docs/gen_api.py
"$CLI_PY" docs/gen_config_tables.py
"$CLI_PY" docs/gen_scene_files.py

# 3. Build (mkdocs.yml has strict: true; --strict makes it explicit).
start=$(date +%s.%N)
"$DOCS_VENV/bin/mkdocs" build --strict --clean --config-file "$ROOT/mkdocs.yml" --site-dir "$SITE_DIR"
end=$(date +%s.%N)
awk -v s="$start" -v e="$end" -v d="$SITE_DIR" 'BEGIN { printf "site in %s (mkdocs build %.1f s)\n", d, e - s }'
