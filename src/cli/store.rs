//! Object storage for `filter` and `batch`: inputs and outputs may be `s3://bucket/prefix`,
//! `gs://bucket/prefix` or `az://container/prefix`, through the `object_store` crate.
//!
//! Configuration is the providers' usual environment: for S3 `AWS_ACCESS_KEY_ID`,
//! `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`, `AWS_REGION` / `AWS_DEFAULT_REGION`,
//! `AWS_ENDPOINT_URL` (an S3-compatible store: MinIO, Ceph, R2, moto), and the web-identity
//! and instance-metadata credentials a cluster gives a pod; for Google Cloud
//! `GOOGLE_SERVICE_ACCOUNT` / `GOOGLE_APPLICATION_CREDENTIALS`; for Azure
//! `AZURE_STORAGE_ACCOUNT_NAME` and `AZURE_STORAGE_ACCOUNT_KEY` (or a SAS / managed identity).
//! `--endpoint URL` overrides the S3 endpoint (plain `http://` is then allowed).
//!
//! A put is one request, so an object appears whole or not at all; reads and writes run on
//! a small tokio runtime of their own, called from the blocking threads of the shot runner.

use afterimage::io::{IoError, LocalFiles, Storage};
use object_store::path::Path as Key;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

/// The URL schemes read and written through the object store.
const SCHEMES: [&str; 3] = ["s3", "gs", "az"];

/// Whether `spec` names an object store location (`s3://`, `gs://`, `az://`).
pub fn is_remote(spec: &str) -> bool {
    SCHEMES
        .iter()
        .any(|s| spec.strip_prefix(s).is_some_and(|rest| rest.starts_with("://")))
}

/// `scheme`, bucket and key of an object store path.
fn split(path: &Path) -> Option<(&'static str, String, String)> {
    let s = path.to_str()?;
    let scheme = SCHEMES
        .into_iter()
        .find(|sc| s.strip_prefix(sc).is_some_and(|rest| rest.starts_with("://")))?;
    let rest = &s[scheme.len() + 3..];
    let (bucket, key) = rest.split_once('/').unwrap_or((rest, ""));
    Some((scheme, bucket.to_string(), key.trim_matches('/').to_string()))
}

/// Every object store bucket, each client made on first use.
pub struct ObjectStorage {
    runtime: tokio::runtime::Runtime,
    endpoint: Option<String>,
    stores: Mutex<HashMap<(String, String), Arc<dyn ObjectStore>>>,
}

static ENDPOINT: OnceLock<Option<String>> = OnceLock::new();
static OBJECTS: OnceLock<Result<Arc<ObjectStorage>, String>> = OnceLock::new();

/// Sets the S3 endpoint (`--endpoint`) before the first object is touched; later calls
/// with the same value are no-ops, a different one is an error.
pub fn set_endpoint(endpoint: Option<String>) -> anyhow::Result<()> {
    let set = ENDPOINT.get_or_init(|| endpoint.clone());
    if *set != endpoint && endpoint.is_some() {
        anyhow::bail!("--endpoint {endpoint:?} differs from the one already in use ({set:?})");
    }
    Ok(())
}

/// Where `spec` lives: the object store for `s3://`, `gs://` and `az://`, else local files.
pub fn storage_for(spec: &str) -> anyhow::Result<Arc<dyn Storage>> {
    if !is_remote(spec) {
        return Ok(Arc::new(LocalFiles));
    }
    let objects = OBJECTS.get_or_init(|| {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("afterimage-objects")
            .enable_all()
            .build()
            .map_err(|e| format!("starting the object store runtime: {e}"))?;
        let endpoint = ENDPOINT
            .get()
            .cloned()
            .flatten()
            .or_else(|| std::env::var("AWS_ENDPOINT_URL").ok());
        Ok(Arc::new(ObjectStorage {
            runtime,
            endpoint,
            stores: Mutex::new(HashMap::new()),
        }))
    });
    match objects {
        Ok(o) => Ok(o.clone()),
        Err(e) => anyhow::bail!("{e}"),
    }
}

/// An object store refusal as an [`IoError`] naming the object, led by what it means where
/// it is one of the usual setup mistakes ([`meaning`]). Its `std::io::Error` has the kind
/// `NotFound` or `PermissionDenied` for those (and for the store's own `NotFound`,
/// `PermissionDenied` and `Unauthenticated` errors), which `batch` does not retry:
/// transient failures were already retried, with backoff, by the store's client.
fn refused(path: &Path, e: impl std::fmt::Display + 'static) -> IoError {
    use std::io::ErrorKind;
    let any: &dyn std::any::Any = &e;
    let kind = match any.downcast_ref::<object_store::Error>() {
        Some(object_store::Error::NotFound { .. }) => ErrorKind::NotFound,
        Some(object_store::Error::PermissionDenied { .. } | object_store::Error::Unauthenticated { .. }) => {
            ErrorKind::PermissionDenied
        }
        _ => ErrorKind::Other,
    };
    let text = e.to_string();
    let error = match split(path).and_then(|(scheme, bucket, _)| meaning(scheme, &bucket, &text)) {
        Some((kind, m)) => std::io::Error::new(kind, format!("{m} ({text})")),
        None => std::io::Error::new(kind, text),
    };
    IoError::os(path, error)
}

/// What an object store's error text means when it is no credentials (the provider's
/// chain ended at the instance metadata service, 169.254.169.254, which refused or did not
/// answer), no such bucket, or access denied, with the kind of error it is; `None` for
/// anything else.
fn meaning(scheme: &str, bucket: &str, text: &str) -> Option<(std::io::ErrorKind, String)> {
    use std::io::ErrorKind;
    let t = text.to_ascii_lowercase();
    let has = |words: &[&str]| words.iter().any(|w| t.contains(w));
    if has(&[
        "169.254.169.254",
        "error getting credentials",
        "no credentials",
        "missing credentials",
    ]) {
        let how = match scheme {
            "s3" => "set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (or AWS_PROFILE, or a web identity), or run where an instance role gives them",
            "gs" => "set GOOGLE_APPLICATION_CREDENTIALS or GOOGLE_SERVICE_ACCOUNT",
            _ => "set AZURE_STORAGE_ACCOUNT_NAME with AZURE_STORAGE_ACCOUNT_KEY (or a SAS token or managed identity)",
        };
        return Some((
            ErrorKind::PermissionDenied,
            format!("no credentials for {scheme}://{bucket}: {how}"),
        ));
    }
    if has(&[
        "nosuchbucket",
        "bucket does not exist",
        "containernotfound",
        "container does not exist",
    ]) {
        return Some((ErrorKind::NotFound, format!("no bucket {scheme}://{bucket}")));
    }
    if has(&[
        "accessdenied",
        "access denied",
        "forbidden",
        "authorizationfailure",
        "status 403",
        "403 forbidden",
    ]) {
        return Some((
            ErrorKind::PermissionDenied,
            format!("access denied to {scheme}://{bucket}: the credentials found are not allowed this"),
        ));
    }
    None
}

impl ObjectStorage {
    /// The client of `path`'s bucket and the object's key.
    fn locate(&self, path: &Path) -> Result<(Arc<dyn ObjectStore>, Key), IoError> {
        let (scheme, bucket, key) = split(path).ok_or_else(|| {
            IoError::Argument(format!(
                "{}: expected s3://BUCKET/KEY, gs://BUCKET/KEY or az://CONTAINER/KEY",
                path.display()
            ))
        })?;
        if bucket.is_empty() {
            return Err(IoError::Argument(format!("{}: no bucket", path.display())));
        }
        let key = Key::parse(&key).map_err(|e| refused(path, e))?;
        let mut stores = self.stores.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = stores.get(&(scheme.to_string(), bucket.clone())) {
            return Ok((s.clone(), key));
        }
        let store: Arc<dyn ObjectStore> = match scheme {
            "s3" => {
                let mut b = object_store::aws::AmazonS3Builder::from_env().with_bucket_name(&bucket);
                if let Some(e) = &self.endpoint {
                    b = b.with_endpoint(e).with_allow_http(e.starts_with("http://"));
                }
                Arc::new(b.build().map_err(|e| refused(path, e))?)
            }
            "gs" => Arc::new(
                object_store::gcp::GoogleCloudStorageBuilder::from_env()
                    .with_bucket_name(&bucket)
                    .build()
                    .map_err(|e| refused(path, e))?,
            ),
            _ => Arc::new(
                object_store::azure::MicrosoftAzureBuilder::from_env()
                    .with_container_name(&bucket)
                    .build()
                    .map_err(|e| refused(path, e))?,
            ),
        };
        stores.insert((scheme.to_string(), bucket), store.clone());
        Ok((store, key))
    }
}

impl Storage for ObjectStorage {
    fn is_local(&self) -> bool {
        false
    }

    fn get(&self, path: &Path) -> Result<Option<Vec<u8>>, IoError> {
        let (store, key) = self.locate(path)?;
        self.runtime.block_on(async {
            match store.get(&key).await {
                Ok(r) => Ok(Some(r.bytes().await.map_err(|e| refused(path, e))?.to_vec())),
                Err(object_store::Error::NotFound { .. }) => Ok(None),
                Err(e) => Err(refused(path, e)),
            }
        })
    }

    fn put(&self, path: &Path, bytes: &[u8]) -> Result<(), IoError> {
        let (store, key) = self.locate(path)?;
        let payload = PutPayload::from(bytes.to_vec());
        self.runtime
            .block_on(store.put(&key, payload))
            .map(|_| ())
            .map_err(|e| refused(path, e))
    }

    fn list(&self, dir: &Path) -> Result<Vec<PathBuf>, IoError> {
        Ok(self.stamps(dir)?.into_iter().map(|(p, _)| p).collect())
    }

    fn delete(&self, path: &Path) -> Result<(), IoError> {
        let (store, key) = self.locate(path)?;
        match self.runtime.block_on(store.delete(&key)) {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(refused(path, e)),
        }
    }

    fn stamps(&self, dir: &Path) -> Result<Vec<(PathBuf, String)>, IoError> {
        let (store, key) = self.locate(dir)?;
        let prefix = (!key.as_ref().is_empty()).then_some(&key);
        let listed = self
            .runtime
            .block_on(store.list_with_delimiter(prefix))
            .map_err(|e| refused(dir, e))?;
        let (scheme, bucket, _) = split(dir).expect("located above");
        Ok(listed
            .objects
            .into_iter()
            .map(|o| {
                let stamp = format!(
                    "{} bytes, modified {}, etag {}",
                    o.size,
                    o.last_modified.to_rfc3339(),
                    o.e_tag.as_deref().unwrap_or("-")
                );
                (
                    PathBuf::from(format!("{scheme}://{bucket}/{}", o.location)),
                    stamp,
                )
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_paths_split_into_bucket_and_key() {
        assert!(
            is_remote("s3://b/k") && is_remote("gs://b") && !is_remote("s3:/b") && !is_remote("shots/s3://x")
        );
        let s = |p: &str| split(Path::new(p));
        assert_eq!(
            s("s3://bkt/a/b.exr"),
            Some(("s3", "bkt".into(), "a/b.exr".into()))
        );
        assert_eq!(s("az://c/dir/"), Some(("az", "c".into(), "dir".into())));
        assert_eq!(s("gs://bkt"), Some(("gs", "bkt".into(), String::new())));
        assert_eq!(s("/tmp/a.exr"), None);
        // The directory of an object, and an object under a directory, keep the scheme.
        let p = Path::new("s3://bkt/out").join("f.0001.exr");
        assert_eq!(p, Path::new("s3://bkt/out/f.0001.exr"));
        assert_eq!(p.parent(), Some(Path::new("s3://bkt/out")));
    }

    /// The usual setup mistakes are named first, the store's own text kept after them.
    #[test]
    fn refusals_say_what_they_mean() {
        let p = Path::new("s3://shots/sh010/beauty.0001.exr");
        use std::io::ErrorKind;
        let kind = |e: &IoError| match e {
            IoError::Os { source, .. } => source.kind(),
            other => panic!("not an OS error: {other}"),
        };
        for (text, says, is) in [
            (
                "Generic S3 error: Error getting credentials from provider: HTTP status client error (403 Forbidden) for url (http://169.254.169.254/latest/api/token)",
                "no credentials for s3://shots: set AWS_ACCESS_KEY_ID",
                ErrorKind::PermissionDenied,
            ),
            (
                "Generic S3 error: Client error with status 404 Not Found: <Error><Code>NoSuchBucket</Code><Message>The specified bucket does not exist</Message></Error>",
                "no bucket s3://shots",
                ErrorKind::NotFound,
            ),
            (
                "Generic S3 error: Client error with status 403 Forbidden: <Error><Code>AccessDenied</Code></Error>",
                "access denied to s3://shots",
                ErrorKind::PermissionDenied,
            ),
        ] {
            let e = refused(p, text.to_string());
            assert_eq!(kind(&e), is, "{e}");
            let e = e.to_string();
            assert!(e.starts_with(&format!("{}: {says}", p.display())), "{e}");
            assert!(e.contains(text), "the store's text is kept: {e}");
        }
        // The store's own kinds of refusal keep theirs; other failures are plain.
        let source = || Box::new(std::io::Error::other("x")) as Box<dyn std::error::Error + Send + Sync>;
        let store = |e: object_store::Error| kind(&refused(p, e));
        assert_eq!(
            store(object_store::Error::NotFound {
                path: "k".into(),
                source: source()
            }),
            ErrorKind::NotFound
        );
        assert_eq!(
            store(object_store::Error::Unauthenticated {
                path: "k".into(),
                source: source()
            }),
            ErrorKind::PermissionDenied
        );
        assert_eq!(
            store(object_store::Error::Generic {
                store: "S3",
                source: source()
            }),
            ErrorKind::Other
        );
        let other = refused(p, "Generic S3 error: connection reset").to_string();
        assert_eq!(
            other,
            format!("{}: Generic S3 error: connection reset", p.display())
        );
        assert!(refused(Path::new("gs://b/x"), "no credentials found")
            .to_string()
            .contains("GOOGLE_APPLICATION_CREDENTIALS"));
    }
}
