"""Command-line interface: parses arguments and calls the library; holds no science.

One module per group of commands (:mod:`.data`: generate, info, show, export; :mod:`.recon`:
reconstruct, methods; :mod:`.learn`: train, predict; :mod:`.study`: evaluate, reproduce,
shift-test, scaling; :mod:`.scan`: import, stack), the options several share declared once in
:mod:`.options`, and the app and its error boundary in :mod:`.entry`.
"""

from .entry import app, main, run

__all__ = ["app", "main", "run"]
