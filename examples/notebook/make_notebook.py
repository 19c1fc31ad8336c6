"""Write examples/notebook/identify.ipynb from the cells below, executed by nbclient.

The committed notebook is this script's output; to remake it, from the repository's root with
the test extras installed (``--no-execute`` writes the cells without outputs)::

    python examples/notebook/make_notebook.py

tests/test_notebook.py executes the notebook again and checks what it displays.
"""

import sys
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    new_markdown_cell(
        "# Identifying m, c, k in a notebook\n\n"
        "The seed paper's Table 1 experiment (`examples/paper-sample`: m = 2 kg, c = 1 N·s/m, "
        "k = 64 N/m, a loop delay of 0.1 s, 19 PD runs) identified with phoid, displayed, "
        "exported to python-control (`pip install 'phoid[control]'`) and to pandas, and the "
        "identified plant's step response plotted with its uncertainty."),
    new_code_cell(
        "%matplotlib inline\n"
        "import matplotlib.pyplot as plt\n"
        "import numpy as np\n\n"
        "import phoid\n\n"
        "experiment = phoid.read_experiment(\"../paper-sample\")\n"
        "experiment"),
    new_markdown_cell(
        "The identification: the estimates ± one standard error, the fit statistics "
        "(χ²/dof, the correlations of the estimates), the per-run table and any warnings."),
    new_code_cell("result = phoid.identify(experiment)\nresult"),
    new_code_cell(
        "print(f\"m = {result.m:.4f} kg, k = {result.k:.2f} N/m, \"\n"
        "      f\"omega0 = {float(result.omega0):.3f} rad/s\")"),
    new_markdown_cell("The estimates and the runs as pandas DataFrames:"),
    new_code_cell("frames = result.to_pandas()\nframes.estimates"),
    new_code_cell("frames.runs.head()"),
    new_markdown_cell(
        "The identified plant G(s) = 1/(m s² + c s + k) as a python-control transfer "
        "function, its step response, and the spread of 200 plants drawn from the estimates' "
        "covariance (`sample_plants`)."),
    new_code_cell(
        "import control\n\n"
        "G = result.to_control()\n"
        "print(G)\n"
        "t = np.linspace(0, 10, 2001)\n"
        "_, y = control.step_response(G, t)\n"
        "spread = np.array([control.step_response(g, t)[1]\n"
        "                   for g in result.sample_plants(200, np.random.default_rng(1), "
        "form=\"tf\")])\n"
        "lo, hi = np.percentile(spread, [2.5, 97.5], axis=0)\n"
        "fig, ax = plt.subplots(figsize=(7, 3.5))\n"
        "ax.fill_between(t, lo * 1e3, hi * 1e3, color=\"C0\", alpha=0.3, "
        "label=\"95 % of sampled plants\")\n"
        "ax.plot(t, y * 1e3, \"C0\", label=\"identified plant\")\n"
        "ax.axhline(1e3 / result.k.value, color=\"k\", lw=0.8, ls=\":\", label=\"1/k\")\n"
        "ax.set(xlabel=\"t (s)\", ylabel=\"x per 1 N step (mm)\", "
        "title=\"Step response of the identified plant\")\n"
        "ax.legend()\n"
        "plt.show()"),
    new_markdown_cell(
        "The closed loop of the first run, with the 0.1 s delay as a Padé approximation of "
        "the order phoid chose (the approximation's error at the dominant pole is in "
        "`.phoid`):"),
    new_code_cell(
        "loop = result.closed_loop(0)\n"
        "info = loop.phoid\n"
        "print(f\"Padé order {info.pade_order}, dominant pole {info.dominant_pole:.4f} (error \"\n"
        "      f\"{info.pole_error:.1e} of phoid's exact root)\")"),
]


def main(argv: list[str]) -> None:
    here = Path(__file__).resolve().parent
    nb = new_notebook(cells=CELLS, metadata={
        "kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}})
    if "--no-execute" not in argv:
        from nbclient import NotebookClient

        NotebookClient(nb, timeout=300, kernel_name="python3",
                       resources={"metadata": {"path": str(here)}}).execute()
    nbformat.write(nb, here / "identify.ipynb")


if __name__ == "__main__":
    main(sys.argv[1:])
