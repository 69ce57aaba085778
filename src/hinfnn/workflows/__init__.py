"""Workflows: each builds a list of run cases (:mod:`hinfnn.experiment`) and a report text.

:mod:`~hinfnn.workflows.run` (``hinfnn run``), :mod:`~hinfnn.workflows.compare` (``hinfnn
compare``), :mod:`~hinfnn.workflows.gallery` (``hinfnn gallery``), :mod:`~hinfnn.workflows.paper`
(``hinfnn reproduce``: the paper's study and "Beyond the paper", its report text in
:mod:`~hinfnn.workflows.paper_report`).
"""
