"""The adaptation QP, min 1/2 (x - x*)^T W (x - x*) s.t. G x <= h: its contract (``problem``), the exact
solver for n <= 2 (``exact``) and its compiled twin (``exact_kernels``), and the PIQP-held solver with the
least-violation fallback (``solver``). Imports no other room of the core."""
