//! The stage graph, capture directory, manifests and the `pipeline` command.
