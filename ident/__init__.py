"""ident: robot dynamics, signals, friction models and estimators, gap diagnosis, studies, CLI."""
