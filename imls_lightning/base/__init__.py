"""The foundation every other package stands on, importing none of them: one-line user errors and the
command-line checks (:mod:`.errors`), the generic validators (:mod:`.validate`), quoting a value for a Hydra
override line (:mod:`.overrides`), atomic file writes (:mod:`.atomic`) and the processes and temporaries a
killed writer leaves (:mod:`.orphans`). Its modules import only the standard library and third-party packages."""
