"""The Indri & Trapani 2020 framework (001): residual torques (:mod:`~ident.indri.data`), the
two-step static and LuGre-type identification (:mod:`~ident.indri.estimator`), indices, tables
and figures (:mod:`~ident.indri.report`), the campaign driver and C code generation."""
