"""Annotation of X-ray images: landmarks, contours and semi-automatic tools."""
