"""oacli: plan, control and learn the model of a free-flying space robot during on-orbit assembly."""

__version__ = "0.1.0"
