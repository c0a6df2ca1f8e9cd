"""The seed papers' own analyses (one package each: paper000, paper001, paper002) and the drum campaign."""
