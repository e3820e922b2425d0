//! The OpenAPI 3.1 description of the HTTP API served at `GET /api/openapi.json`,
//! generated from the handlers: each handler states its path, summary, parameters,
//! request body and answers in a `#[utoipa::path]` attribute, and its request and
//! response types derive `utoipa::ToSchema`. The router (`api::routes`) registers every
//! handler through `utoipa_axum::routes!`, which takes the route and its description
//! from that one attribute, so a route cannot be served undescribed. What the checks in
//! front of a group of routes answer (401, 415, 413, 400 for a body that is not JSON)
//! is described here once, for every route behind them ([`describe_access`]), and what
//! every route may answer (421 for a Host that is not the daemon's) in [`finish`].
//!
//! Why utoipa (5, with `utoipa-axum`) rather than aide: utoipa's `OpenApiRouter`
//! registers a handler and its description in one step while the router stays a plain
//! axum 0.8 `Router` with its `route_layer`s (the token and JSON checks are middleware
//! over groups of routes, which aide's `ApiRouter` would have to be told about per
//! route through transform functions); the description is plain data we can extend
//! per group; and the schema derives work on the existing serde types (internally
//! tagged enums, `Option` as `null`) without a second trait such as `JsonSchema`.

use utoipa::openapi::extensions::ExtensionsBuilder;
use utoipa::openapi::path::{Operation, ParameterIn};
use utoipa::openapi::response::{Response, ResponseBuilder};
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme};
use utoipa::openapi::{
    ContentBuilder, InfoBuilder, KnownFormat, ObjectBuilder, OpenApi, PathItem, Ref, RefOr,
    SchemaFormat, Type,
};
use utoipa::PartialSchema;

use crate::answers::ErrorBody;

/// The checks a group of routes is behind, beyond the Host check every request passes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Anyone who may reach the daemon: the page, health, this description.
    Open,
    /// Reads: open on loopback or with `public_read`, else behind the token.
    Read,
    /// Changes: behind the token.
    Token,
    /// Changes with a JSON body: behind the token and `Content-Type: application/json`.
    TokenJson,
}

/// The extension naming a path's last parameter that takes the rest of the path,
/// slashes included (axum's `{*name}`; OpenAPI's parameters take one segment).
const REST_OF_PATH: &str = "x-rest-of-path";

/// The security scheme's name: `Authorization: Bearer <token>`.
const BEARER: &str = "bearer";

/// The shared answers, by name (`#/components/responses/<name>`), and what they say.
const SHARED_ANSWERS: [(&str, &str); 8] = [
    (
        "BadParameter",
        "A path or query parameter is not of its type (an id that is not a whole number, \
         a number that does not parse); nothing changed",
    ),
    (
        "MisdirectedRequest",
        "The Host header is not the bind address, localhost or a name of allowed_hosts \
         (DNS rebinding); nothing changed",
    ),
    (
        "UnsupportedMediaType",
        "The body's Content-Type is not application/json; nothing changed",
    ),
    (
        "BodyTimeout",
        "The body did not arrive whole within header_timeout_s (the connection closes \
         after the answer); nothing changed",
    ),
    (
        "Unauthorized",
        "Missing or wrong bearer token (`WWW-Authenticate: Bearer`); nothing changed",
    ),
    (
        "ReadUnauthorized",
        "Bound beyond loopback without public_read: missing or wrong bearer token",
    ),
    (
        "BodyTooLarge",
        "The body is over max_body_bytes (the connection closes after the answer); \
         nothing changed",
    ),
    (
        "Internal",
        "An internal fault (the journal could not be read, a worker task failed), named",
    ),
];

/// Adds to every operation of a group what its checks answer (where the handler's own
/// description does not say it already) and its security requirement.
pub fn describe_access(access: Access, api: &mut OpenApi) {
    let answers: &[(&str, &str)] = match access {
        Access::Open => &[],
        Access::Read => &[("401", "ReadUnauthorized"), ("500", "Internal")],
        Access::Token => &[("401", "Unauthorized"), ("500", "Internal")],
        Access::TokenJson => &[
            ("401", "Unauthorized"),
            ("413", "BodyTooLarge"),
            ("408", "BodyTimeout"),
            ("415", "UnsupportedMediaType"),
            ("500", "Internal"),
        ],
    };
    let bearer = || SecurityRequirement::new(BEARER, Vec::<String>::new());
    let security = match access {
        Access::Open => None,
        Access::Read => Some(vec![SecurityRequirement::default(), bearer()]),
        Access::Token | Access::TokenJson => Some(vec![bearer()]),
    };
    for operation in api.paths.paths.values_mut().flat_map(operations) {
        add_answers(operation, answers);
        if security.is_some() {
            operation.security = security.clone();
        }
    }
}

/// Completes the description the routes gave: its title and conventions, the error
/// shape and shared answers, the bearer scheme, the 421 every route may answer, and
/// axum's catch-all `{*path}` written as OpenAPI's `{path}` (with [`REST_OF_PATH`]).
pub fn finish(mut api: OpenApi) -> OpenApi {
    api.info = InfoBuilder::new()
        .title("gonio daemon")
        .version(env!("CARGO_PKG_VERSION"))
        .description(Some(
            "Image-based BRDF measurement: durable scan queue, live progress, results. \
             Angles in degrees, shutter times in seconds. Mutating routes need \
             `Authorization: Bearer <token>`. Every request's Host must be the daemon's \
             bind address, localhost or a name of `allowed_hosts` (else 421). Bound \
             beyond loopback, reads need the token too unless `public_read = true`. \
             Errors are `{\"error\": \"...\"}`, with `field` naming an invalid field. A \
             body over `max_body_bytes` is answered 413 on any route. A connection \
             beyond `max_connections` when none is idle is answered 503 and closed \
             before its request is read. Generated from the handlers' types.",
        ))
        .build();
    for operation in api.paths.paths.values_mut().flat_map(operations) {
        add_answers(operation, &[("421", "MisdirectedRequest")]);
        for answer in operation.responses.responses.values_mut() {
            if let RefOr::T(answer) = answer {
                bytes_as_binary(answer);
            }
        }
    }
    api.paths.paths = std::mem::take(&mut api.paths.paths)
        .into_iter()
        .map(|(path, mut item)| {
            // A parameter of the wrong type is axum's 400, before the handler.
            let typed = path.contains("{id}")
                || operations(&mut item).any(|o| {
                    o.parameters
                        .iter()
                        .flatten()
                        .any(|p| p.parameter_in == ParameterIn::Query)
                });
            if typed {
                for operation in operations(&mut item) {
                    add_answers(operation, &[("400", "BadParameter")]);
                }
            }
            if let Some((_, rest)) = path.split_once("{*") {
                let name = rest.trim_end_matches('}');
                item.extensions = Some(ExtensionsBuilder::new().add(REST_OF_PATH, name).build());
            }
            (path.replace("{*", "{"), item)
        })
        .collect();
    let components = api.components.get_or_insert_with(Default::default);
    components
        .schemas
        .insert("Error".to_owned(), ErrorBody::schema());
    for (name, description) in SHARED_ANSWERS {
        components
            .responses
            .insert(name.to_owned(), RefOr::T(error_answer(description)));
    }
    components.security_schemes.insert(
        BEARER.to_owned(),
        SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
    );
    api
}

/// Every operation of a path, whatever its method.
fn operations(item: &mut PathItem) -> impl Iterator<Item = &mut Operation> {
    [
        &mut item.get,
        &mut item.put,
        &mut item.post,
        &mut item.delete,
        &mut item.options,
        &mut item.head,
        &mut item.patch,
        &mut item.trace,
    ]
    .into_iter()
    .filter_map(Option::as_mut)
}

/// Adds each `(status, shared answer)` the operation does not describe itself.
fn add_answers(operation: &mut Operation, answers: &[(&str, &str)]) {
    for (status, name) in answers {
        operation
            .responses
            .responses
            .entry((*status).to_owned())
            .or_insert_with(|| RefOr::Ref(Ref::from_response_name(*name)));
    }
}

/// A body that is neither JSON nor text (a file, an archive, a PNG) as OpenAPI's
/// binary string, not the array of integers a `Vec<u8>` is described as.
fn bytes_as_binary(answer: &mut Response) {
    for (media_type, content) in &mut answer.content {
        if media_type != "application/json" && !media_type.starts_with("text/") {
            let binary = ObjectBuilder::new()
                .schema_type(Type::String)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)));
            content.schema = Some(RefOr::T(binary.into()));
        }
    }
}

/// An answer in the API's error shape.
fn error_answer(description: &str) -> Response {
    ResponseBuilder::new()
        .description(description)
        .content(
            "application/json",
            ContentBuilder::new()
                .schema(Some(Ref::from_schema_name("Error")))
                .build(),
        )
        .build()
}
