"""The example notebook (examples/python_tour.ipynb) run end to end by nbclient on a fresh
kernel of this venv, as Jupyter would: every cell without an error, every frame shown
inline as a PNG. The executed notebook and its pictures are left in target/notebook/."""

import base64
import os

import pytest

from _support import ROOT, shared


NOTEBOOK = ROOT / "examples" / "python_tour.ipynb"


def test_the_example_notebook_runs_end_to_end():
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    data = shared()
    nb = nbformat.read(NOTEBOOK, as_version=4)
    os.environ["VOLTERRA_SHARED_DATA"] = str(data)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()
    out = ROOT / "target" / "notebook"
    out.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, out / NOTEBOOK.name)
    pictures = []
    for k, cell in enumerate(nb.cells):
        for o in cell.get("outputs", []):
            assert o.get("output_type") != "error", (k, o)
            png = o.get("data", {}).get("image/png")
            if png:
                pictures.append(k)
                (out / f"cell_{k:02}.png").write_bytes(base64.b64decode(png))
    # Six frames shown by their _repr_png_ and one matplotlib figure.
    assert len(pictures) == 7, pictures
    montage(sorted(out.glob("cell_*.png")), out / "montage.png")


def montage(paths, target, height=240):
    """The notebook's pictures side by side in rows of four (docs/images/python_tour.png)."""
    Image = pytest.importorskip("PIL.Image")
    images = [Image.open(p).convert("RGB") for p in paths]
    images = [im.resize((round(im.width * height / im.height), height)) for im in images]
    rows = [images[i : i + 4] for i in range(0, len(images), 4)]
    width = max(sum(im.width for im in row) for row in rows)
    sheet = Image.new("RGB", (width, height * len(rows)), "white")
    for r, row in enumerate(rows):
        x = 0
        for im in row:
            sheet.paste(im, (x, r * height))
            x += im.width
    sheet.save(target)
