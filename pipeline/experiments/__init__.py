"""The experiment commands beside the benchmark's runs: each measures a question over many runs or states
(``python -m pipeline.experiments.<name>``): ``duel`` (paired one-step decisions between two methods, with
``decisions`` and ``duel_summary``), ``discriminate``, ``uncertainty``, ``visibility_study`` (with
``visibility_summary``) and ``budget_curve``; ``options`` holds what their command lines share."""
