"""Running trained networks: the methods and the IML/S renderer with its one selective
render-and-scatter and stage timing (:mod:`.pipeline`), and loading checkpoints with their
cross-checks (:mod:`.checkpoints`)."""
