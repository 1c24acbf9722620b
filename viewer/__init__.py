"""phyir-view: the interactive panorama inspector and object-insertion editor (owns all GL)."""
