// The daemon's HTTP API as the page uses it: every call names this page's client
// (X-Camd-Client) and turns an error answer into an Error carrying the daemon's own message.
// The token, if the daemon has one, travels in the camd_token cookie (set by /live?token=).

export const API = "/api/v1";

function pickClientName() {
  const fromUrl = new URLSearchParams(location.search).get("client");
  if (fromUrl) {
    sessionStorage.setItem("camd-client", fromUrl);
    return fromUrl;
  }
  let name = sessionStorage.getItem("camd-client");
  if (!name) {
    const random = Math.floor(Math.random() * 0xffff).toString(16).padStart(4, "0");
    name = `web-${random}`;
    sessionStorage.setItem("camd-client", name);
  }
  return name;
}

export const CLIENT = pickClientName();

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

async function raiseFor(response) {
  let code = "http_error";
  let message = `${response.status} ${response.statusText}`;
  try {
    const body = await response.json();
    code = body.code ?? code;
    message = body.error ?? message;
  } catch (_) {
    // not JSON: keep the status line
  }
  throw new ApiError(response.status, code, message);
}

export async function call(method, path, body) {
  const init = { method, headers: { "X-Camd-Client": CLIENT }, cache: "no-store" };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const response = await fetch(API + path, init);
  if (!response.ok) await raiseFor(response);
  if (response.status === 204) return null;
  return response.json();
}

// A binary answer: [metadata from the named header (JSON), ArrayBuffer], or null on 404.
export async function binary(path, header) {
  const response = await fetch(API + path, { headers: { "X-Camd-Client": CLIENT }, cache: "no-store" });
  if (response.status === 404) return null;
  if (!response.ok) await raiseFor(response);
  const meta = JSON.parse(response.headers.get(header) ?? "{}");
  return [meta, await response.arrayBuffer()];
}

export const get = (path) => call("GET", path);
export const post = (path, body) => call("POST", path, body ?? {});
export const put = (path, body) => call("PUT", path, body);
export const del = (path) => call("DELETE", path);
