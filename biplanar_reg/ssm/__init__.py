"""Shape models: the SSM itself, templates, populations and model building."""

from .model import ShapeModel

__all__ = ["ShapeModel"]
