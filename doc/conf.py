"""
Sphinx configuration of the suture_lfd manual (rosdoc2's layout: ``doc/`` holds the sources).

Built by ``./suture-lfd docs`` into ``doc/_build/html``. The reference pages of the nodes, the
command line, the configuration files and the Python API are generated at build time from the
code's own declarations by the ``generated_reference`` extension (``doc/_ext``).
"""

from pathlib import Path
import sys

DOC = Path(__file__).resolve().parent
sys.path.insert(0, str(DOC / '_ext'))
sys.path.insert(0, str(DOC.parent))

project = 'suture_lfd'
author = 'suture_lfd maintainers'
copyright = '2026, suture_lfd maintainers'  # noqa: A001 (Sphinx's name)

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.autosummary',
    'numpydoc',
    'generated_reference',
]

source_suffix = {'.md': 'markdown', '.rst': 'restructuredtext'}
root_doc = 'index'
exclude_patterns = ['_build', '_generated_sources']
myst_enable_extensions = ['colon_fence', 'deflist']
myst_heading_anchors = 3

autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {'members': True, 'undoc-members': False, 'show-inheritance': False}
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

html_theme = 'furo'
html_title = 'suture_lfd manual'
html_static_path: list[str] = []
templates_path = ['_templates']
html_show_sourcelink = False
