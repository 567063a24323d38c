"""Body, skeleton, skinning, garment, cage and the rest-pose embedding of the garment on the body."""
