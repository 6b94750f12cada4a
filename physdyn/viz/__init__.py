"""Looking at motion: the interactive viewer page (``viewer``), its scenes of a store's sequences
(``store_scenes``) and GIF/MP4 animations (``render``)."""
