"""The Indri & Trapani 2020 framework (001): residuals, static and LuGre-type identification, indices, campaign driver, C code generation."""
