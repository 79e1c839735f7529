"""Signals over the frames of a clip: where staggered poses are (paper 4.1, SPEC 4).

* :mod:`.trails`: motion trails, their scaled curvature and the variables'
  weights: the local evidence;
* :mod:`.smoothing`: Laplacian smoothing and the tent filter, in seconds;
* :mod:`.probability`: the pose probability, its local maxima and the poses'
  priorities;
* :mod:`.placement`: the placement proxy, what a pose between two others
  costs (the spacing of staggered poses).
"""
