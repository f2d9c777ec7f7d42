"""Fused kernels behind the public functions (private).

Each kernel computes the same mathematics as a readable reference in the public module
that owns the concept, faster: component-row layout, cache-sized chunks, custom autograd
``Function``s with an analytic (twice differentiable) backward. ``tests/test_kernels.py``
runs each against its reference over random and degenerate inputs.

- :mod:`.weights`: the dual weights of eq. 11 as one power series (shared by all kernels).
- :mod:`.layout`: component rows and chunking.
- :mod:`.sclerp`: eq. 11 (reference: :func:`torch_dq.dualquat._eq11`).
- :mod:`.slerp`: quaternion slerp on the shortest path, the real part of eq. 11, in the
  caller's ``(N, 4)`` layout (reference: :func:`torch_dq._kernels.slerp.plain`, the same
  forward to the bit).
- :mod:`.dual_angle`: eqs. 4-5 (reference: :func:`torch_dq.dualquat._eqs4_5`).
- :mod:`.pyramid`: the fused De Casteljau / De Boor scheme (references in
  :mod:`torch_dq.curves`).
- :mod:`.products`: dual-quaternion products as matrix products, for small batches (the
  cumulative B-spline's span tables, :mod:`.cumulative`).
- :mod:`.cumulative`, :mod:`.cumulative_jets`, :mod:`.cumulative_rows`, :mod:`.subsets`: the
  cumulative B-spline form's poses and time derivatives through span tables (reference:
  :func:`torch_dq._cumulative.jets`).
- :mod:`.sincos`: the dual sine and cosine (reference: :func:`torch_dq.dual._sincos`).
- :mod:`.jet_sclerp`, :mod:`.jet_pyramid`: eq. 11 and the triangular scheme on Taylor jets
  (the weights' op :class:`.jet_sclerp._WeightJets`; jet arithmetic: :mod:`torch_dq._taylor`).
- :mod:`.native`, :mod:`.lie_native`: the optional compiled C loops (``csrc``, through
  :mod:`ctypes`): the cumulative form's vjp and evaluation in its Lie algebra (reference:
  ``torch_dq._cumulative_lie``).

Every public function chooses between kernel and reference the same way
(:mod:`torch_dq._dispatch`); the helpers of the custom ops are in :mod:`torch_dq._autograd`.
The modules import each other and the layers below, never this package.
"""
