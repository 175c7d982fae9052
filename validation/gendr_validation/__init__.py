"""gendr_validation — reference renderers, hard-limit and finite-difference checks, reports, goldens.

Independent of the backends' internals: it renders through the public :class:`gendr.Renderer` API
and compares with pyrender and Mitsuba 3 (:mod:`.references`). Entry points:

* ``gendr validate [--quick|--full] -o OUTDIR`` (:func:`.cli.validate_main`, a ``gendr.commands`` plug-in): HTML report + JSON summary;
* ``gendr gallery -o docs/gallery`` (:mod:`.gallery`): the documentation figures;
* ``python -m gendr_validation.goldens --regenerate`` (:mod:`.goldens`): the regression goldens.

See docs/validation.md.
"""
from .references import (Reference, PyrenderReference, MitsubaReference, ReferenceUnavailableError,
                         get_reference, REFERENCES, DEFAULT_REFERENCES)
from .cameras import camera_geometry, edge_distance, project_polygons

__all__ = ["Reference", "PyrenderReference", "MitsubaReference", "ReferenceUnavailableError", "get_reference",
           "REFERENCES", "DEFAULT_REFERENCES", "camera_geometry", "edge_distance", "project_polygons"]
