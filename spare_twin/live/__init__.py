"""`spare-twin live`: a stream of frames -> a recording, incremental registration, `predict`'s core at
least once a second, the view in Rerun (`live.session` says how the parts fit)."""
