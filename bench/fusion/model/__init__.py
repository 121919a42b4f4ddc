"""The estimator as one explicit state-space model (issue 26).

Every effect is a state or a measurement with a stated noise, each in one function:

- :mod:`.state`: the state's named fields and the model's parameters (physical units);
- :mod:`.process`: f (the motion and track), F = df/dx, Q (the process noise);
- :mod:`.measure`: h, H, R for the odometer and for the three raw channel readings;
- :mod:`.ekf`: one generic predict and one generic update in Joseph form;
- :mod:`.smoother`: the Rauch-Tung-Striebel fixed-interval smoother on the same model.

All numerical functions are compiled by numba (``NUMBA_DISABLE_JIT=1`` runs them as plain
Python, as the tests do once); they use scalar loops and no reductions whose order could
change, so a run gives the same bits however its samples are batched.
"""
