"""Measuring mscloth against brute force (``mscloth compare``, ``make bench``); the renderer
never imports it (tests/test_layout.py). One concern per module:

* :mod:`.metrics`: relMSE, FLIP, estimators of noise per sample and squared bias;
* :mod:`.renders`: a built-in scene, multi-scale or brute force, and one timed render;
* :mod:`.regions`: the near / middle / far cloth pixels, by camera distance;
* :mod:`.references`: the brute-force reference and its on-disk cache;
* :mod:`.speedup`: the equal-error speed-up and how far a region's can be trusted;
* :mod:`.report`: the HTML report and its figures;
* :mod:`.compare`: the comparison itself (:func:`.compare.run_compare`);
* :mod:`.error_budget`: noise per sample by light, and each method's bias.

Plots and FLIP need the ``evaluation`` extra (matplotlib, flip-evaluator).
"""
