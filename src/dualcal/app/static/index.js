// The projects page: create a project through the API, then open it.
"use strict";
document.getElementById("new-project").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.target, error = document.getElementById("new-error");
  const body = {};
  for (const [key, value] of new FormData(form)) if (String(value).trim() !== "") body[key] = String(value).trim();
  error.textContent = "";
  const response = await fetch("/api/projects", {method: "POST", headers: {"content-type": "application/json"},
                                                 body: JSON.stringify(body)});
  const doc = await response.json();
  if (response.status === 201) window.location.href = "/projects/" + encodeURIComponent(doc.id);
  else error.textContent = doc.error || ("the project could not be created (" + response.status + ")");
});
