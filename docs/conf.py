"""
Sphinx configuration of the sb3_pride documentation (Markdown pages through MyST, API pages through autodoc).

    pip install -e ".[docs]" && sphinx-build -W --keep-going -b html docs docs/_build/html

The build imports ``sb3_pride`` (autodoc reads the docstrings of the installed package); HTML is never committed.
"""

import os

os.environ.setdefault("MUJOCO_GL", "disable")  # importing the package makes no window and needs no display

import sb3_pride

project = "sb3_pride"
author = "sb3_pride contributors"
copyright = "sb3_pride contributors"
version = release = sb3_pride.__version__

extensions = ["myst_parser", "sphinx.ext.autodoc"]
source_suffix = {".md": "markdown"}
root_doc = "index"
# _generated/ holds pages written by scripts, included by hand-written pages (never pages of their own)
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]

myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3  # [text](page.md#a-heading) links

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"show-inheritance": True}

html_theme = "furo"
html_title = f"sb3_pride {release}"
