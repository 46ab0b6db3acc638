"""The tutorial notebook (docs/notebook/tutorial.ipynb) executed from a copy of its folder: no cell may raise,
nothing may be written beside it, every cell tagged "figure" shows a figure; its HTML (nbconvert) opened in headless
Chromium shows every figure and logs no error."""
from __future__ import annotations

import shutil
from pathlib import Path

import nbformat
import pytest
from browser import chromium
from nbclient import NotebookClient
from nbconvert import HTMLExporter

FOLDER = Path(__file__).resolve().parent.parent / "docs" / "notebook"


def test_the_tutorial_runs_writes_nothing_and_renders_every_figure(tmp_path, browser):
    folder = tmp_path / "notebook"
    shutil.copytree(FOLDER, folder)
    before = sorted(p.name for p in folder.iterdir())
    notebook = nbformat.read(folder / "tutorial.ipynb", as_version=4)
    # a cell that raises stops here with its traceback (nbclient's CellExecutionError)
    NotebookClient(notebook, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(folder)}}).execute()
    assert sorted(p.name for p in folder.iterdir()) == before, "the tutorial wrote files"
    tagged = [c for c in notebook.cells if "figure" in c.metadata.get("tags", [])]
    assert len(tagged) >= 5
    shown = [sum("image/png" in o.get("data", {}) for o in c.get("outputs", [])) for c in tagged]
    assert shown == [1] * len(tagged), f"figures shown per tagged cell: {shown}"
    untagged = [c for c in notebook.cells if c.cell_type == "code" and c not in tagged]
    assert not any("image/png" in o.get("data", {}) for c in untagged for o in c.get("outputs", []))
    # the objects show themselves as tables in the page
    html_outputs = [o for c in untagged for o in c.get("outputs", []) if "text/html" in o.get("data", {})]
    assert sum("<table" in o["data"]["text/html"] for o in html_outputs) >= 6

    page = tmp_path / "tutorial.html"
    exporter = HTMLExporter(template_name="lab", extra_template_basedirs=[str(folder)],
                            template_file=str(folder / "offline.html.j2"))
    page.write_text(exporter.from_notebook_node(notebook)[0])
    assert "<script src=" not in page.read_text()  # nothing from the web: the page opens offline
    browser.get(page.as_uri())
    loaded = browser.execute_script(
        "return Array.from(document.images).filter(i => i.complete && i.naturalWidth > 100).length")
    assert loaded == len(tagged)
    assert [e for e in browser.get_log("browser") if e["level"] == "SEVERE"] == []


@pytest.fixture(scope="module")
def browser():
    with chromium() as driver:
        yield driver
