//! Code generated from `proto/afterimage/v1/afterimage.proto` by `build.rs`.
#![allow(missing_docs, clippy::all, clippy::pedantic)]

tonic::include_proto!("afterimage.v1");
