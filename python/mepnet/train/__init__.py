"""Training the detector: settings (:mod:`.config`), data (:mod:`.data`), checkpoints
(:mod:`.checkpoint`), the loop (:mod:`.loop`), metrics files (:mod:`.log`), torchrun
(:mod:`.distributed`) and ``python -m mepnet.train`` (:mod:`.cli`)."""
