"""MkDocs hook: the benchmark results (``benches/*_results.md``, written by the benches beside
their code) and the viewer's screenshots (``benches/shots/``) become pages and images of the site
without a copy in ``docs/``: ``benchmarks/<name>.md`` and ``benchmarks/shots/<file>``."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]


def on_files(files, config):
    benches = ROOT / "benches"
    for results in sorted(benches.glob("*_results.md")):
        name = results.name.removesuffix("_results.md")
        files.append(File.generated(config, f"benchmarks/{name}.md", abs_src_path=str(results)))
    for shot in sorted((benches / "shots").glob("*.png")):
        files.append(File.generated(config, f"benchmarks/shots/{shot.name}", abs_src_path=str(shot)))
    return files
