"""Recordings: the file format's names (:mod:`engine.recording.format`, a leaf), the recorder
(writer), the reader, replay and its diff, ``replay --update``, ``vgr play``, the live view and
``vgr topics``.

Layer: may import everything in the engine but cli; the reader imports no zenoh and no runner.
"""
