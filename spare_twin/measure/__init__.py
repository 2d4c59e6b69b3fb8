"""Measurement: the chain measured on the object's points, with no network (the classical estimator).

Sits above `observe` (posed views -> the object's points -> the chain's profile) and below `nets`
and `predict`. `layers` counts the links layer by layer and fits the chain (lengths, joint angles);
`chain` measures a recording's chain, trying parts of a sweep whose registration blurred it;
`slots` holds a measurement in the fixed-size arrays a batch of network outputs has."""
