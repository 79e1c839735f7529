"""Contacts (paper Appendix B, SPEC section 6): where a foot, a toe or a
marker is planted, and how a bake keeps it so.

* :mod:`.constraint`: a contact constraint (joint, span, source span);
* :mod:`.detect`: finding contacts, the up axis and the floor, default contact joints;
* :mod:`.ik`: analytic two-bone IK and the blended IK layer;
* :mod:`.layer`: the contact layer of a bake (which contacts an edit disturbed, their targets, the warnings).
"""
