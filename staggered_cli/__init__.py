"""staggered: editable staggered poses from dense motion capture (Coleman et al., SCA 2008).

The library under the ``staggered`` command::

    import staggered_cli as st
    clip = st.read("walk.bvh")                  # a BVH or C3D clip, or a document, by content
    doc = st.extract(clip)                      # staggered poses, refinements, contacts
    doc = st.cull(doc, keep="30%")
    doc = st.succession(doc, joint="@left-arm", offset=0.03, power=1.5, clamp=True)
    st.write(st.bake(doc), "walk_loose.bvh")    # atomic; refuses an existing file unless force=True

One function per command, document first, the command's options as
keywords.  Values are immutable.  Errors derive from :class:`StaggeredError`
(:class:`DataError` for bad data, :class:`UsageError` for bad arguments);
what an edit cannot do as asked is a :class:`StaggeredWarning`.
"""

from . import api as _api
from .api import *  # noqa: F403  (the public functions: api.__all__)
from .errors import DataError, StaggeredError, StaggeredWarning, UsageError

__version__ = "0.1.0"

__all__ = [*_api.__all__, "StaggeredError", "DataError", "UsageError", "StaggeredWarning"]
