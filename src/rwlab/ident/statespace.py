"""State-space identification, re-exported from the modules that hold it.

``rwlab.ident.statespace`` was one module; it is now :mod:`rwlab.ident.ssmodel`
(the model, ``SSModel``), :mod:`rwlab.ident.subspace` (``n4sid``) and
:mod:`rwlab.ident.sspem` (``ssest``). This name stays importable for old code.
"""

from rwlab.ident.ssmodel import SSModel
from rwlab.ident.sspem import ssest
from rwlab.ident.subspace import n4sid

__all__ = ["SSModel", "n4sid", "ssest"]
