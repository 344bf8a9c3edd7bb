"""What a person or a program reads of runs: the text and JSON of ``show``, ``runs`` and
``compare`` (:mod:`.format_text`, :mod:`.format_json`), the figures (:mod:`.figures`),
the HTML report of a run, a pipeline or a JND file (:mod:`.report` and its sections,
built on :mod:`.page`) and the outputs of a comparison of objectives
(:mod:`.comparison_outputs`).

It reads what :mod:`evo_door.experiment` stores and runs nothing of it: the layer above
``experiment``, below the commands.
"""
