"""The runs of gazepipe's stages: each reads the take's files through :mod:`gazepipe.io` and its declared tables
through the unit's context, calls its stage's pure function (:mod:`gazepipe.stages`) and returns the tables it
writes (laid out by :mod:`gazepipe.schemas`). One module per stage; :mod:`.common` holds what they share.

Readers and stage functions are imported inside the runs: planning needs only the declarations
(:mod:`gazepipe.dag.takes`), so a run with nothing to do never pays for importing scipy.signal, pandas or OpenCV.
"""
