"""Design: learning the rotation map θ, choosing the nanofin, and the reconstruction network.

- The lens's learning (``metalens optimize``): ``model`` (what a run learns and its plan),
  ``parameterization`` (θ radial or 2-D), ``step`` (one step: draws, windows, batch, the step),
  ``training`` (the session, its estimate, validation), ``train_loop`` (resume, checkpoints,
  Ctrl-C), ``distributed`` (torchrun), ``losses``, ``scenes``, ``features`` (L_DA),
  ``filter_learning`` (the filter learned with θ), ``rundir`` and ``report`` (the run's files).
- The nanofin (``metalens nanofin``): ``fin_efficiency``, ``fin_choice``, ``fin_files``.
- The back end (``metalens reconstruct``): ``reconstruct_data``, ``reconstruct_training``.
"""
