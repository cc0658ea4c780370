"""The p/tau-adaptive computed-torque controller (paper section 4: ``controller``, compiled period
``controller_kernels``, arrays ``controller_layout``) and the whole-body stage of its ``wbc`` and ``hybrid``
modes (``wbc``, compiled ``wbc_kernels``). Imports the ``qp`` and ``sensing`` rooms."""
