"""MkDocs hook: the notebooks live in notebooks/ at the repository root (where the tests
run them); this adds them to the site as notebooks/<name>.ipynb, before mkdocs-jupyter
turns .ipynb files into pages."""

from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"


@event_priority(100)  # before the plugins' on_files (mkdocs-jupyter's runs at the default 0)
def on_files(files, config):
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        files.append(File(f"notebooks/{path.name}", src_dir=str(NOTEBOOKS.parent), dest_dir=config["site_dir"],
                          use_directory_urls=config["use_directory_urls"]))
    return files
