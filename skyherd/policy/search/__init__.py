"""Search for a lost UGV (issue 29, item 4): dead-reckon where it should be from its last known
position and heading, fly there while climbing toward the envelope's ceiling to widen the view,
then an expanding-square search around the prediction. `lost`: the tracker and the search;
`study`: re-acquisition on the speed-off and camouflage scenarios
(`python -m skyherd.policy.search.study`). docs/search.md."""
