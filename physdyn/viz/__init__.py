"""Looking at motion: the interactive viewer page (``viewer``), its scenes of a store's sequences
(``store_scenes``), GIF/MP4 animations (``render``), and the mesh both draw, cut to a face budget
(``meshes``)."""
