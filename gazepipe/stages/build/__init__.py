"""The ``build`` stage (SPEC §3.6, §4): the training datasets from every take's tables.

Takes: the per-take tables each dataset needs (``gaze_rnn``: joints and eyes; ``gaze_rnn_lod``: joints;
``gaze_map``: joints and the cleaned markers' rest periods; ``face_clean``: face). Gives: per dataset, one table
per take (rows with identifier columns, the take's split, mirrored copies) and the ``_dataset.json`` object
(feature names, training statistics overall and per pose, counts, input hashes, parameters). Records: the takes
left out and why, and the counts, in ``_dataset.json`` and the dataset's run record.

Read top-down: :mod:`.stage` (:func:`build_dataset`) makes each take's part (:func:`take_part`: its rows through
:mod:`.gaze` (the gaze datasets) or :mod:`.face` (face_clean), :mod:`.mirror` (the mirrored copies), its table and
the facts :mod:`.summary` needs of it), then merges the parts (:class:`DatasetMerge`: take-disjoint train / val /
test by :mod:`.splits`, _dataset.json accumulated one take at a time). A run makes the parts in the takes' own
units, on the workers (:mod:`gazepipe.dag.builds`), and only merges them in the dataset's build.
"""

from gazepipe.stages import lazy_exports

__all__ = ["BuildParams", "BuiltDataset", "DatasetMerge", "TakePart", "TakeTables", "build_dataset", "take_part"]
__getattr__ = lazy_exports(__name__, {name: ".stage" for name in __all__})
