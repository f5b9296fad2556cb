"""Coast-down identification (000): TDM, FDM and the ML/NLS estimator."""
